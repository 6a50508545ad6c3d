"""Caps on concurrent clients, so that no crowd of sockets can take the file descriptors
the recorder needs: without a cap, a thousand telemetry sockets leave none for its files
and recording fails with EMFILE.

Every client holds a socket: the main server's plain HTTP connections, WebSockets and
MJPEG viewers, and the 3D panels' viewers (which come through the main server too and are
relayed to the panels' viser servers over loopback, server/trajectory3d/gate.py). At
start one budget is fitted under the process's descriptor limit (RLIMIT_NOFILE, first
raised to its hard limit) minus a reserve for the recorder, the link and the cameras, and
shared out:

    budget = nofile - BASELINE_FDS - reserve
    ├── 2 x viewers3d  both ends of each 3D viewer's loopback connection to viser
    └── connections    every TCP connection of the main server, of which at most
        ├── control      CONTROL_CLIENTS places of the pilot's own
        ├── websocket    /ws/telemetry
        ├── video        MJPEG viewers and `/ws/video` pages (one place per page)
        └── viewers3d    3D viewers (both panels together)
        and at least HTTP_ROOM always free for plain requests (`/api/health`, pages).

A streaming client beyond its cap is refused with 503 in the error shape, before it
costs anything. The caps are thread-safe.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import resource
import threading
from collections.abc import Iterator

from fpv_station.server.errors import Unavailable

log = logging.getLogger(__name__)

# What a running station holds besides its clients: logs, the link, the cameras, viser's
# own sockets, the event loop, the recorder's files. Measured idle at ~60 on the twin.
BASELINE_FDS = 96
# Control sockets (/ws/control: the pilot page, goggles, a laptop or two) have places of
# their own: a crowd of anonymous telemetry sockets must not lock the pilot out.
CONTROL_CLIENTS = 8
# Main-server connections no streaming client may take: plain requests (health checks,
# pages, the control API) always find a place, after idle ones are closed for them.
HTTP_ROOM = 8
# Descriptors a 3D viewer holds: its connection to the main server and both ends of its
# relay's loopback connection to the panel's viser server.
VIEWER3D_FDS = 3


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
    """One kind of client and how many may be connected at once."""

    kind: str  # "websocket", "video", "control", "3D viewer" or "connection"
    limit: int
    active: int = 0
    refused: int = 0
    _lock: threading.Lock = dataclasses.field(
        default_factory=threading.Lock, repr=False, compare=False
    )

    def try_take(self) -> bool:
        """Take one place; False (and counted as refused) when every place is taken.
        Safe from any thread; each True must be matched by one `give_back`."""
        with self._lock:
            if self.active >= self.limit:
                self.refused += 1
                return False
            self.active += 1
            return True

    def give_back(self) -> None:
        """Free a place taken with `try_take`."""
        with self._lock:
            self.active = max(0, self.active - 1)

    def _full(self) -> Unavailable:
        return Unavailable(
            f"The station serves at most {self.limit} {self.kind} clients at once; "
            "try again when one has left."
        )

    def check(self) -> None:
        """Unavailable (503) when every place is taken; takes nothing."""
        with self._lock:
            if self.active >= self.limit:
                self.refused += 1
                raise self._full()

    def take(self) -> None:
        """Take one place; Unavailable (503) when every place is taken."""
        if not self.try_take():
            raise self._full()

    @contextlib.contextmanager
    def slot(self) -> Iterator[None]:
        """Hold one client's place for the `with` block; Unavailable (503) when full."""
        self.take()
        try:
            yield
        finally:
            self.give_back()


def _default_connections() -> ClientCap:
    return ClientCap("connection", 256)


def _default_viewers3d() -> ClientCap:
    return ClientCap("3D viewer", 20)


@dataclasses.dataclass
class ClientLimits:
    websocket: ClientCap  # /ws/telemetry
    video: ClientCap
    control: ClientCap = dataclasses.field(
        default_factory=lambda: ClientCap("control", CONTROL_CLIENTS)
    )
    # Every TCP connection of the main server (counted by server/listen.py).
    connections: ClientCap = dataclasses.field(default_factory=_default_connections)
    # The 3D panels' viewers, both viser servers together (server/trajectory3d/).
    viewers3d: ClientCap = dataclasses.field(default_factory=_default_viewers3d)

    @classmethod
    def fitted(
        cls, max_ws: int, max_video: int, reserve: int, nofile: int, max_3d: int = 20
    ) -> ClientLimits:
        """The configured caps, lowered to fit `nofile` descriptors with `reserve` spare."""
        budget = max(nofile - BASELINE_FDS - reserve, HTTP_ROOM + CONTROL_CLIENTS + 3)
        ws, video, viewers3d = max_ws, max_video, max_3d
        room = budget - HTTP_ROOM - CONTROL_CLIENTS  # for ws, video and 3D viewers
        if ws + video + VIEWER3D_FDS * viewers3d > room:
            video = min(video, max(1, room // 5))
            viewers3d = min(viewers3d, max(1, room // (5 * VIEWER3D_FDS)))
            ws = max(1, room - video - VIEWER3D_FDS * viewers3d)
            log.warning(
                "descriptor limit %d: serving at most %d WebSocket, %d video and %d 3D "
                "clients (%d kept for the recorder)",
                nofile,
                ws,
                video,
                viewers3d,
                reserve,
            )
        return cls(
            ClientCap("websocket", ws),
            ClientCap("video", video),
            connections=ClientCap(
                "connection", ws + video + viewers3d + CONTROL_CLIENTS + HTTP_ROOM
            ),
            viewers3d=ClientCap("3D viewer", viewers3d),
        )
