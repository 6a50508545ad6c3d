"""`WS /ws/telemetry`: the vehicle state pushed to each browser as soon as it changes.

One coroutine per client sends what the station's telemetry pump (server/telemetry_pump.py)
gives it: one message per tick, built once and shared by every client that is due, at
most `?max_rate=` per second for that client (default `server.telemetry_rate_hz`, 50).
The send stays in the client's own coroutine: a client that reads slowly (or not at all) blocks only itself in
`send_text`, then skips to the newest message; nothing queues and no client delays
another.

`?ack=N`: bounded staleness for slow clients (a busy phone, goggles on weak Wi-Fi). The
kernel's socket buffers hold whatever `send_text` handed over, so a client that reads
slowly still falls seconds behind without it. With acks the station keeps at most N
unacknowledged messages in flight: the client sends `{"ack": <version>}` after handling
messages, which acknowledges every message up to that version, and once N are
unacknowledged the next message waits, then is the newest one at that moment, never a
queue. `?ack=1` acknowledges each message. The pages use `?ack=2` and acknowledge every
second message (web/telemetry.js): the station reads half the acks of `?ack=1` (each one
a wake-up of the Pi's event loop, docs/PERFORMANCE.md) for at most two messages in
flight, and as with `?ack=1` the ack has until the next tick to arrive before the page's
rate drops.
"""

from __future__ import annotations

import asyncio
import contextlib

import orjson
from fastapi import APIRouter, Query, WebSocket, WebSocketDisconnect

from fpv_station.server.errors import Unavailable, deny_websocket
from fpv_station.server.station import Station
from fpv_station.server.telemetry_pump import TelemetryClient, TelemetryPump
from fpv_station.server.ws_acks import ack_of, ack_window_query, read_until_disconnect

router = APIRouter(tags=["telemetry"])
# The largest frame a client may send: an ack is a few bytes (server/listen.py closes the
# socket with 1009 on a larger frame, before reading it).
MAX_FRAME_BYTES = 1024


class _ClientAcks:
    """Reads what the client sends until it disconnects; hands each `{"ack": n}` to the
    pump, which counts the client in for the next tick (no wake-up of the client's
    coroutine for an ack: a page acknowledges every second message, 25 a second)."""

    def __init__(self, pump: TelemetryPump, client: TelemetryClient) -> None:
        self._pump = pump
        self._client = client

    async def read_until_disconnect(self, ws: WebSocket) -> None:
        try:
            await read_until_disconnect(ws, self._note)
        finally:
            self._client.leave()  # a coroutine waiting for its next message ends now

    def _note(self, text: str | None) -> None:
        # Without a window nothing is read; an ack is tiny, anything else is ignored.
        if not self._client.ack_window or not text or len(text) > 100:
            return
        try:
            ack = ack_of(orjson.loads(text))  # 50 a second for two pages: in C
        except ValueError:
            return
        if ack is not None:
            self._pump.acked(self._client, ack)


@router.websocket("/ws/telemetry")
async def ws_telemetry(
    ws: WebSocket,
    # At least 1/s: a slower feed is of no use to a page (and a value like 1e-300 would
    # park its client for good).
    max_rate: float | None = Query(
        None, ge=1, le=1000, description="messages per second, at most (default: the station's)"
    ),
    ack: int = ack_window_query('{"ack": version} acknowledges every message up to version'),
) -> None:
    station = ws.app.state.station
    try:
        with station.client_limits.websocket.slot():
            rate = max_rate or station.settings.server.telemetry_rate_hz
            await _serve_telemetry(ws, station, rate, ack)
    except Unavailable as exc:
        await deny_websocket(ws, 503, "Unavailable", exc.message)


async def _serve_telemetry(ws: WebSocket, station: Station, max_rate: float, ack: int) -> None:
    pump = station.telemetry
    await ws.accept()
    client = TelemetryClient(max_rate, ack)
    # Held and cancelled below: it notices the client leaving (and reads its acks).
    watcher = asyncio.ensure_future(_ClientAcks(pump, client).read_until_disconnect(ws))
    try:
        await pump.join(client)
        while (message := await pump.next_message(client)) is not None:
            await ws.send_text(message.text)
    except (WebSocketDisconnect, RuntimeError, ConnectionError):
        pass  # the client went away mid-send
    finally:
        pump.leave(client)
        watcher.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await watcher
        with contextlib.suppress(RuntimeError, WebSocketDisconnect):
            await ws.close()  # raises if the client already left
