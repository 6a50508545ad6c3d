"""`WS /ws/telemetry`: the vehicle state pushed to each browser as soon as it changes.

One coroutine per client sends what the station's telemetry pump (server/telemetry_pump.py)
gives it: one message per tick, built once and shared by every client that is due, at
most `?max_rate=` per second for that client (default `server.telemetry_rate_hz`, 50). The send stays in the
client's own coroutine: a client that reads slowly (or not at all) blocks only itself in
`send_text`, then skips to the newest message; nothing queues and no client delays
another.

`?ack=1`: bounded staleness for slow clients (a busy phone, goggles on weak Wi-Fi). The
kernel's socket buffers hold whatever `send_text` handed over, so a client that reads
slowly still falls seconds behind without it. With acks the station keeps at most one
unacknowledged message in flight: the client sends `{"ack": <version>}` after handling a
message, and the next message is the newest one at that moment, never a queue.
"""

from __future__ import annotations

import asyncio
import contextlib

import orjson
from fastapi import APIRouter, Query, WebSocket, WebSocketDisconnect

from server.errors import Unavailable, deny_websocket
from server.station import Station
from server.telemetry_pump import TelemetryClient

router = APIRouter(tags=["telemetry"])


class _ClientAcks:
    """Reads what the client sends until it disconnects; keeps the newest `{"ack": n}`.

    An ack, and the leaving, wake the client's coroutine (`TelemetryClient.wait`): no
    timer per wait, a page acknowledges every message, 50 a second."""

    def __init__(self, client: TelemetryClient) -> None:
        self.acked = 0
        self._client = client

    async def read_until_disconnect(self, ws: WebSocket) -> None:
        try:
            with contextlib.suppress(WebSocketDisconnect, RuntimeError):
                while True:
                    msg = await ws.receive()
                    if msg["type"] == "websocket.disconnect":
                        return
                    self._note(msg.get("text"))
        finally:
            self._client.leave()  # a coroutine waiting for an ack or a tick ends now

    def _note(self, text: str | None) -> None:
        if not text or len(text) > 100:  # an ack is tiny; anything else is ignored
            return
        try:
            ack = orjson.loads(text).get("ack")  # 100 a second for two pages: in C
        except (ValueError, AttributeError):
            return
        if isinstance(ack, int) and not isinstance(ack, bool) and ack > self.acked:
            self.acked = ack
            self._client.wake()

    async def wait_for(self, version: int) -> bool:
        """True once `version` is acknowledged; False when the client has gone."""
        client = self._client
        while self.acked < version and not client.gone:
            await client.wait()
        return not client.gone


@router.websocket("/ws/telemetry")
async def ws_telemetry(
    ws: WebSocket,
    # At least 1/s: a slower feed is of no use to a page (and a value like 1e-300 would
    # park its client for good).
    max_rate: float | None = Query(
        None, ge=1, le=1000, description="messages per second, at most (default: the station's)"
    ),
    ack: bool = Query(False, description='at most one message in flight: send {"ack": version}'),
) -> None:
    station = ws.app.state.station
    try:
        with station.client_limits.websocket.slot():
            rate = max_rate or station.settings.server.telemetry_rate_hz
            await _serve_telemetry(ws, station, rate, ack)
    except Unavailable as exc:
        await deny_websocket(ws, 503, "Unavailable", exc.message)


async def _serve_telemetry(ws: WebSocket, station: Station, max_rate: float, ack: bool) -> None:
    pump = station.telemetry
    await ws.accept()
    client = TelemetryClient(max_rate)
    acks = _ClientAcks(client)
    # Held and cancelled below: it notices the client leaving (and reads its acks).
    watcher = asyncio.ensure_future(acks.read_until_disconnect(ws))
    version = 0
    try:
        await pump.join(client)
        while not client.gone:
            if ack and not await acks.wait_for(version):
                break  # gone while its last message was in flight
            message = await pump.next_message(client)
            if message is None:
                break  # gone, or the state slot closed (the station stops)
            await ws.send_text(message.text)
            version = message.version
    except (WebSocketDisconnect, RuntimeError, ConnectionError):
        pass  # the client went away mid-send
    finally:
        pump.leave(client)
        watcher.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await watcher
        with contextlib.suppress(RuntimeError, WebSocketDisconnect):
            await ws.close()  # raises if the client already left
