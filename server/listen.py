"""The listening socket uvicorn serves on and the connections it accepts.

Every connection counted. Each TCP connection holds a descriptor, so the main server
keeps a table of its connections, under the descriptor budget's `connections` cap
(server/client_limits.py), and a connection may not sit idle:

- a request (headers and body) must arrive within `REQUEST_TIMEOUT_S` of the connection
  opening, and the next one within the same time of the previous response (the
  keep-alive timeout): otherwise the connection is closed. uvicorn's own keep-alive
  timer starts only after a response and stops at the first byte, so a client that
  never sends, or sends a byte a second, would hold its descriptor for ever;
- when the table is full, a new connection closes the one that has waited longest for
  its request, so a crowd of idle sockets cannot keep `/api/health` or the control API
  out; when every connection is busy (streams are capped below the table's size) the
  new one is answered 503 and closed;
- uvicorn accepts at most `ACCEPT_BURST` connections per wake-up (asyncio takes the
  backlog as that count), so a queue of waiting connections cannot take a burst of
  descriptors at once, nor close a connection accepted on the turn before, whose
  request has not been read yet; the kernel's queue stays `LISTEN_QUEUE` long.

A connection upgraded to a WebSocket keeps its place until it closes, and each
WebSocket route has a frame limit (`app.state.ws_frame_limits`, bytes by path) fitted
to its messages: a larger frame is refused as it starts, with close code 1009, before
its payload is read.

Slow viewers do not see old video.

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
import contextlib
import functools
import json
import logging
import socket
import time
from typing import Any

import uvicorn
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol
from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol
from websockets.http11 import Request

from fpv_station.companion.latest import Wakeup
from fpv_station.server.client_limits import ClientCap
from fpv_station.server.errors import DenialLogFilter
from fpv_station.server.guard import redact_tokens_in_logs

log = logging.getLogger(__name__)

NOTSENT_LOWAT_BYTES = 64 * 1024  # about one 640x480 JPEG
STALLED_GRACE_S = 0.5  # at shutdown, how long a client that does not read may catch up
_TCP_NOTSENT_LOWAT = getattr(socket, "TCP_NOTSENT_LOWAT", 25)  # 25 on Linux
REQUEST_TIMEOUT_S = 5.0  # from connect (or the last response) to a complete request
ACCEPT_BURST = 16  # connections accepted per wake-up: well under the table's size
LISTEN_QUEUE = 128  # connections the kernel holds until they are accepted
# A WebSocket path the app gives no limit (it refuses the upgrade anyway).
DEFAULT_WS_FRAME_BYTES = 4096
SUMMARY_EVERY_S = 60.0  # closed idle connections are logged at most this often


class ConnectionTable:
    """The main server's open connections: each holds a place of the `connections` cap;
    those waiting for a request are kept oldest first, to be closed when a new one needs
    the place."""

    def __init__(self, app: Any) -> None:
        self._app = app
        self._fallback = ClientCap("connection", 1024)  # an app without a station (tests)
        self.waiting: dict[StationHttpProtocol, None] = {}  # insertion order: oldest first
        self.timed_out = 0  # no complete request in time
        self.evicted = 0  # closed, waiting, for a newer connection
        self.refused = 0  # answered 503: every place busy
        self._logged_at = 0.0
        self._logged = (0, 0, 0)

    @property
    def cap(self) -> ClientCap:
        station = getattr(getattr(self._app, "state", None), "station", None)
        return station.client_limits.connections if station is not None else self._fallback

    def frame_limit(self, path: str) -> int:
        limits = getattr(getattr(self._app, "state", None), "ws_frame_limits", None) or {}
        return limits.get(path, DEFAULT_WS_FRAME_BYTES)

    def admit(self) -> bool:
        """A place for a new connection: free, or taken from the oldest waiting one."""
        cap = self.cap
        if cap.try_take():
            return True
        if self.waiting:
            oldest = next(iter(self.waiting))
            oldest.drop()  # frees its place now; its socket closes on the next turn
            self.evicted += 1
            self._summary()
            return cap.try_take()
        self.refused += 1
        self._summary()
        return False

    def _summary(self) -> None:
        now = time.monotonic()
        counts = (self.timed_out, self.evicted, self.refused)
        if now - self._logged_at < SUMMARY_EVERY_S or counts == self._logged:
            return
        self._logged_at, self._logged = now, counts
        log.warning(
            "connections: %d closed without a request in time, %d idle closed for newer "
            "ones, %d refused (%d places)",
            *counts,
            self.cap.limit,
        )


_BUSY_BODY = json.dumps(
    {
        "error": "Unavailable",
        "error_msg": "The station has no free connection; try again shortly.",
    }
).encode()
_BUSY = (
    b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\n"
    b"content-length: " + str(len(_BUSY_BODY)).encode() + b"\r\nconnection: close\r\n\r\n"
) + _BUSY_BODY


class StationHttpProtocol(HttpToolsProtocol):
    """uvicorn's HTTP protocol, counted in the `ConnectionTable` and closed when no
    complete request comes in time."""

    def __init__(self, *args: Any, table: ConnectionTable, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.table = table
        self.holds_place = False
        self._deadline: asyncio.TimerHandle | None = None

    # asyncio.Protocol's parameter is a BaseTransport; uvicorn's protocols take the
    # asyncio.Transport the loop gives a TCP connection, and so does this one.
    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        if not self.table.admit():
            transport.write(_BUSY)
            transport.close()
            return
        self.holds_place = True
        self._wait_for_request()

    def connection_lost(self, exc: Exception | None) -> None:
        self._release()
        super().connection_lost(exc)

    def drop(self) -> None:
        """Close the connection now and free its place."""
        self._release()
        self.transport.abort()

    def _release(self) -> None:
        self._stop_waiting()
        if self.holds_place:
            self.holds_place = False
            self.table.cap.give_back()

    def _wait_for_request(self) -> None:
        self.table.waiting[self] = None
        self._deadline = self.loop.call_later(REQUEST_TIMEOUT_S, self._too_slow)

    def _stop_waiting(self) -> None:
        self.table.waiting.pop(self, None)
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _too_slow(self) -> None:
        self._deadline = None
        if not self.transport.is_closing():
            self.table.timed_out += 1
            self.drop()

    def on_headers_complete(self) -> None:
        # Busy from here: not closed for a newer connection; the body still has to come
        # before the deadline.
        self.table.waiting.pop(self, None)
        super().on_headers_complete()

    def on_message_complete(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None
        super().on_message_complete()

    def on_response_complete(self) -> None:
        idle = not self.pipeline
        super().on_response_complete()
        if idle and self.holds_place and not self.transport.is_closing():
            self._stop_waiting()
            self._wait_for_request()

    def handle_websocket_upgrade(self) -> None:
        self._stop_waiting()
        super().handle_websocket_upgrade()
        ws = self.transport.get_protocol()
        if isinstance(ws, StationWebSocketProtocol) and self.holds_place:
            ws.holds_place, self.holds_place = True, False  # the place goes with the socket


class StationWebSocketProtocol(WebSocketsSansIOProtocol):
    """uvicorn's WebSocket protocol, keeping the connection's place until it closes and
    taking its route's frame limit at the handshake."""

    def __init__(self, *args: Any, table: ConnectionTable, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.table = table
        self.holds_place = False

    def handle_connect(self, event: Request) -> None:
        path = event.path.partition("?")[0]
        self.conn.max_message_size = self.table.frame_limit(path)
        super().handle_connect(event)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.holds_place:
            self.holds_place = False
            self.table.cap.give_back()
        super().connection_lost(exc)

    def shutdown(self) -> None:
        # The client's close came first: it was answered and the transport is closing
        # (with bytes its client never took, it stays so until dropped). uvicorn would
        # send a close of its own on it, which raises and ends the server's shutdown
        # before the station's own (the recording's) runs.
        if not self.close_sent and self.transport.is_closing():
            self.stop_keepalive()
            return
        super().shutdown()


def listening_socket(host: str, port: int, backlog: int = LISTEN_QUEUE) -> socket.socket:
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

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        await super().startup(sockets)
        # asyncio listened with the backlog uvicorn passed (ACCEPT_BURST): the kernel's
        # queue may be longer than a burst.
        for server in getattr(self, "servers", []):
            for sock in server.sockets:
                with (
                    contextlib.suppress(OSError),
                    socket.fromfd(sock.fileno(), sock.family, sock.type) as dup,
                ):
                    dup.listen(LISTEN_QUEUE)  # the same socket, through a copy of its fd

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
            conn.transport.abort()
        if stalled:
            log.info("shutdown: closed %d connections whose clients stopped reading", len(stalled))


def _unsent_bytes(conn: object) -> int:
    """Bytes a connection (HTTP or WebSocket) holds that its client has not taken: the
    kernel's buffer is full, so the transport keeps them. A closing transport counts too:
    it waits for them to go before it closes."""
    transport = getattr(conn, "transport", None)
    return 0 if transport is None else transport.get_write_buffer_size()


def uvicorn_server(app, log_level: str = "info") -> uvicorn.Server:
    """The uvicorn server as `fpv-station serve` runs it (tests run the same one).

    No permessage-deflate: browsers ask for it, and it would compress every telemetry
    message once per client, the per-client re-encoding the shared JSON body avoids.
    Streams end at shutdown (`StationServer`); a response still running after 2 s (a
    viewer stalled in a socket write, a download) is cancelled. Connections are counted
    and timed (`ConnectionTable`).
    """
    table = ConnectionTable(app)
    # uvicorn types `http` and `ws` as protocol classes; it only calls them with the
    # protocol's arguments, as a partial of the class is called.
    config = uvicorn.Config(
        app,
        log_level=log_level,
        http=functools.partial(StationHttpProtocol, table=table),  # type: ignore[arg-type]
        ws=functools.partial(StationWebSocketProtocol, table=table),  # type: ignore[arg-type]
        ws_max_size=DEFAULT_WS_FRAME_BYTES,
        ws_per_message_deflate=False,
        timeout_keep_alive=int(REQUEST_TIMEOUT_S),
        timeout_graceful_shutdown=2,
        backlog=ACCEPT_BURST,
        lifespan="on",
    )
    # After the Config: it configures uvicorn's loggers. Once per logger, however many
    # servers a process runs (the tests run many).
    errors = logging.getLogger("uvicorn.error")
    if not any(isinstance(f, DenialLogFilter) for f in errors.filters):
        errors.addFilter(DenialLogFilter())
    redact_tokens_in_logs()  # uvicorn's handlers are new
    return StationServer(config)
