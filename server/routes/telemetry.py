"""`WS /ws/telemetry`: the vehicle state pushed to each browser as soon as it changes.

One coroutine per client, each reading the station's latest-value slot: a client that
reads slowly (or not at all) blocks only its own coroutine in `send_text`, then skips
to the newest state; nothing queues and no client delays another. `?max_rate=` caps
the messages per second for that client (default 50). The JSON body is built once per
state version and shared (`server.telemetry_json`).

`?ack=1`: bounded staleness for slow clients (a busy phone, goggles on weak Wi-Fi). The
kernel's socket buffers hold whatever `send_text` handed over, so a client that reads
slowly still falls seconds behind without it. With acks the station keeps at most one
unacknowledged message in flight: the client sends `{"ack": <version>}` after handling a
message, and the next message is the newest state at that moment, never a queue.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time

from fastapi import APIRouter, Query, WebSocket, WebSocketDisconnect

from companion.latest import wait_resolved
from server.errors import Unavailable, deny_websocket
from server.station import Station

router = APIRouter(tags=["telemetry"])

_IDLE_CHECK_S = 1.0  # how often an idle handler looks whether its client went away


class _ClientAcks:
    """Reads what the client sends until it disconnects; keeps the newest `{"ack": n}`.

    The handler waits on a plain future that an ack (or the leave) resolves
    (`companion.latest.wait_resolved`): a page acknowledges every message, 50 a second."""

    def __init__(self) -> None:
        self.acked = 0
        self.gone = False
        self._waiter: asyncio.Future[None] | None = None

    async def read_until_disconnect(self, ws: WebSocket) -> None:
        try:
            with contextlib.suppress(WebSocketDisconnect, RuntimeError):
                while True:
                    msg = await ws.receive()
                    if msg["type"] == "websocket.disconnect":
                        return
                    self._note(msg.get("text"))
        finally:
            self.gone = True
            self._wake()  # a handler waiting for an ack ends now

    def _note(self, text: str | None) -> None:
        if not text or len(text) > 100:  # an ack is tiny; anything else is ignored
            return
        try:
            ack = json.loads(text).get("ack")
        except (ValueError, AttributeError):
            return
        if isinstance(ack, int) and not isinstance(ack, bool) and ack > self.acked:
            self.acked = ack
            self._wake()

    def _wake(self) -> None:
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    async def wait_for(self, version: int, within_s: float) -> bool:
        """True once `version` is acknowledged; False when the client has gone, or when
        `within_s` passed (or an older ack came) without it: the caller asks again."""
        if self.acked < version and not self.gone:
            self._waiter = asyncio.get_running_loop().create_future()
            try:
                await wait_resolved(self._waiter, within_s)
            finally:
                self._waiter = None
        return self.acked >= version and not self.gone


@router.websocket("/ws/telemetry")
async def ws_telemetry(
    ws: WebSocket,
    # At least 1/s: a handler paced slower would sit out a client's leaving (and a value
    # like 1e-300 would park it for good).
    max_rate: float = Query(50.0, ge=1, le=1000, description="messages per second, at most"),
    ack: bool = Query(False, description='at most one message in flight: send {"ack": version}'),
) -> None:
    station = ws.app.state.station
    try:
        with station.client_limits.websocket.slot():
            await _serve_telemetry(ws, station, max_rate, ack)
    except Unavailable as exc:
        await deny_websocket(ws, 503, "Unavailable", exc.message)


async def _serve_telemetry(ws: WebSocket, station: Station, max_rate: float, ack: bool) -> None:
    slot = station.state
    shared = station.telemetry_json
    min_interval_s = 1.0 / max_rate
    await ws.accept()
    acks = _ClientAcks()
    # Held and cancelled below: it notices the client leaving (and reads its acks).
    watcher = asyncio.ensure_future(acks.read_until_disconnect(ws))
    version = 0
    next_send = 0.0
    try:
        while not watcher.done():
            # The pause first, then the waits: a state that came during the pause is sent
            # at once, the states the pause skipped never wake this handler, and neither
            # does an ack that came during it (a page acks within a few ms of 20).
            delay = next_send - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)
            if ack and not await acks.wait_for(version, _IDLE_CHECK_S):
                continue  # the last message is still in flight: look again for a leave
            current = await slot.wait_newer(version, timeout=_IDLE_CHECK_S)
            if slot.closed:
                break
            if current is None or current.version <= version:
                continue
            await ws.send_text(shared.message(current))
            version = current.version
            next_send = time.monotonic() + min_interval_s
    except (WebSocketDisconnect, RuntimeError, ConnectionError):
        pass  # the client went away mid-send
    finally:
        watcher.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await watcher
        with contextlib.suppress(RuntimeError, WebSocketDisconnect):
            await ws.close()  # raises if the client already left
