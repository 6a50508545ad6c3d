"""The listening socket uvicorn serves on, tuned so that slow viewers do not see old video.

Linux lets a TCP socket queue megabytes of unsent data (send-buffer autotuning up to
`tcp_wmem` max, 4 MB by default): for an MJPEG viewer on a weak link that is seconds
of stale frames in the kernel, out of reach of the server's "skip to the newest frame".
TCP_NOTSENT_LOWAT caps the unsent bytes instead, so the socket stops accepting data
early, uvicorn's flow control makes the stream wait, and the stream then takes the
newest frame. Data in flight is not limited, so throughput on a good link is unchanged.
Accepted connections inherit the option from the listening socket.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import time

import uvicorn

from companion.latest import Wakeup
from server.errors import DenialLogFilter

log = logging.getLogger(__name__)

NOTSENT_LOWAT_BYTES = 64 * 1024  # about one 640x480 JPEG
STALLED_GRACE_S = 0.5  # at shutdown, how long a client that does not read may catch up
_TCP_NOTSENT_LOWAT = getattr(socket, "TCP_NOTSENT_LOWAT", 25)  # 25 on Linux


def listening_socket(host: str, port: int, backlog: int = 128) -> socket.socket:
    """A bound, listening TCP socket for `host:port` (IPv6 when host has a colon)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if family == socket.AF_INET6 and host in ("::", ""):
            sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 0)
        try:
            sock.setsockopt(socket.IPPROTO_TCP, _TCP_NOTSENT_LOWAT, NOTSENT_LOWAT_BYTES)
        except OSError as exc:  # not Linux/macOS: streams still work, with deeper buffers
            log.info("TCP_NOTSENT_LOWAT unavailable (%s); slow viewers may lag more", exc)
        sock.bind((host, port))
        sock.listen(backlog)
    except OSError:
        sock.close()
        raise
    sock.set_inheritable(True)
    return sock


class StationServer(uvicorn.Server):
    """uvicorn, ending the station's endless streams when its shutdown begins.

    At shutdown uvicorn closes WebSockets (1012) and waits for HTTP responses to finish;
    MJPEG streams never finish by themselves, so after `timeout_graceful_shutdown` it
    would cancel them, logging a traceback per viewer. `app.state.station.end_streams()`
    ends them first: each viewer's response completes after the part it is sending.

    uvicorn's main loop also wakes ten times a second to see whether it should exit; an
    idle station must cost nothing (every wake-up costs a Pi, docs/PERFORMANCE.md), so
    here it wakes once a second, for the Date header, and at once when `should_exit` is
    set (a signal handler, a test's thread).
    """

    def __init__(self, config: uvicorn.Config) -> None:
        self._exit_wakeup = Wakeup()  # before uvicorn's __init__ sets should_exit
        super().__init__(config)

    @property
    def should_exit(self) -> bool:
        return self._should_exit

    @should_exit.setter
    def should_exit(self, value: bool) -> None:
        self._should_exit = value
        if value:
            self._exit_wakeup.wake()

    async def main_loop(self) -> None:
        counter = 0
        while not await self.on_tick(counter):
            # on_tick does its once-a-second work (the Date header) when counter % 10 == 0.
            counter = (counter + 10) % 864000
            await self._exit_wakeup.wait(1.0)

    async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
        station = getattr(getattr(self.config.app, "state", None), "station", None)
        if station is not None:
            station.end_streams()
        await self._drop_stalled_writers()
        await super().shutdown(sockets)

    async def _drop_stalled_writers(self) -> None:
        """A viewer that does not read (a frozen browser) holds its response in a socket
        write that will never finish, so its stream cannot end: after a short grace,
        close such connections at once (nothing more can reach that client anyway)."""
        deadline = time.monotonic() + STALLED_GRACE_S
        while True:
            stalled = [c for c in self.server_state.connections if _unsent_bytes(c)]
            if not stalled or time.monotonic() >= deadline:
                break
            await asyncio.sleep(0.05)
        for conn in stalled:
            conn.transport.abort()  # type: ignore[attr-defined]
        if stalled:
            log.info("shutdown: closed %d connections whose clients stopped reading", len(stalled))


def _unsent_bytes(conn: object) -> int:
    """Bytes a connection (HTTP or WebSocket) holds that its client has not taken: the
    kernel's buffer is full, so the transport keeps them."""
    transport = getattr(conn, "transport", None)
    if transport is None or transport.is_closing():
        return 0
    return transport.get_write_buffer_size()


def uvicorn_server(app, log_level: str = "info") -> uvicorn.Server:
    """The uvicorn server as `fpv-station serve` runs it (tests run the same one).

    No permessage-deflate: browsers ask for it, and it would compress every telemetry
    message once per client, the per-client re-encoding the shared JSON body avoids.
    Streams end at shutdown (`StationServer`); a response still running after 2 s (a
    viewer stalled in a socket write, a download) is cancelled.
    """
    config = uvicorn.Config(
        app,
        log_level=log_level,
        ws_per_message_deflate=False,
        timeout_graceful_shutdown=2,
        lifespan="on",
    )
    # After the Config: it configures uvicorn's loggers. Once per logger, however many
    # servers a process runs (the tests run many).
    errors = logging.getLogger("uvicorn.error")
    if not any(isinstance(f, DenialLogFilter) for f in errors.filters):
        errors.addFilter(DenialLogFilter())
    return StationServer(config)
