"""Caps on concurrent streaming clients, so that no crowd of sockets can take the file
descriptors the recorder needs (issue 13: 1,050 telemetry sockets once made recording
fail with EMFILE for good).

Every WebSocket and MJPEG viewer holds a socket. At start the caps are fitted under the
process's descriptor limit (RLIMIT_NOFILE, first raised to its hard limit) minus a reserve
for the recorder, the link, the cameras and the viser panels. A client beyond its cap is
refused with 503 in the error shape, before it costs anything.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import resource
from collections.abc import Iterator

from server.errors import Unavailable

log = logging.getLogger(__name__)

# What a running station holds besides its clients: logs, the link, the cameras, viser's
# own sockets, the event loop, the recorder's files. Measured idle at ~60 on the twin.
BASELINE_FDS = 96
# Control sockets (/ws/control: the pilot page, goggles, a laptop or two) have places of
# their own: a crowd of anonymous telemetry sockets must not lock the pilot out.
CONTROL_CLIENTS = 8


def raise_nofile_limit() -> int:
    """Raise the soft RLIMIT_NOFILE to the hard one (a Pi's default soft limit is 1,024
    while the hard one is far above); returns the soft limit in force."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard == resource.RLIM_INFINITY:
        hard = max(soft, 65536)
    if soft < hard:
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
    return soft


@dataclasses.dataclass
class ClientCap:
    """One kind of streaming client and how many may be connected at once."""

    kind: str  # "websocket", "video" or "control"
    limit: int
    active: int = 0
    refused: int = 0

    def check(self) -> None:
        """Unavailable (503) when every place is taken."""
        if self.active >= self.limit:
            self.refused += 1
            raise Unavailable(
                f"The station serves at most {self.limit} {self.kind} clients at once; "
                "try again when one has left."
            )

    @contextlib.contextmanager
    def slot(self) -> Iterator[None]:
        """Hold one client's place for the `with` block; Unavailable (503) when full."""
        self.check()
        self.active += 1
        try:
            yield
        finally:
            self.active -= 1


@dataclasses.dataclass
class ClientLimits:
    websocket: ClientCap  # /ws/telemetry
    video: ClientCap
    control: ClientCap = dataclasses.field(
        default_factory=lambda: ClientCap("control", CONTROL_CLIENTS)
    )

    @classmethod
    def fitted(cls, max_ws: int, max_video: int, reserve: int, nofile: int) -> ClientLimits:
        """The configured caps, lowered to fit `nofile` descriptors with `reserve` spare."""
        room = max(nofile - BASELINE_FDS - reserve - CONTROL_CLIENTS, 2)
        ws, video = max_ws, max_video
        if ws + video > room:
            video = max(1, min(video, room // 5))
            ws = max(1, room - video)
            log.warning(
                "descriptor limit %d: serving at most %d WebSocket and %d video clients "
                "(%d kept for the recorder)",
                nofile,
                ws,
                video,
                reserve,
            )
        return cls(ClientCap("websocket", ws), ClientCap("video", video))
