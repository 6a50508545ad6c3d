"""`WS /ws/telemetry`: the vehicle state pushed to each browser as soon as it changes.

One coroutine per client, each reading the station's latest-value slot: a client that
reads slowly (or not at all) blocks only its own coroutine in `send_text`, then skips
to the newest state; nothing queues and no client delays another. `?max_rate=` caps
the messages per second for that client (default 50). The JSON body is built once per
state version and shared (`server.telemetry_json`).
"""

from __future__ import annotations

import asyncio
import contextlib
import time

from fastapi import APIRouter, Query, WebSocket, WebSocketDisconnect

router = APIRouter(tags=["telemetry"])

_IDLE_CHECK_S = 1.0  # how often an idle handler looks whether its client went away


async def _until_disconnect(ws: WebSocket) -> None:
    """Read (and ignore) what the client sends; returns when it disconnects."""
    with contextlib.suppress(WebSocketDisconnect, RuntimeError):
        while True:
            msg = await ws.receive()
            if msg["type"] == "websocket.disconnect":
                return


@router.websocket("/ws/telemetry")
async def ws_telemetry(
    ws: WebSocket,
    max_rate: float = Query(50.0, gt=0, le=1000, description="messages per second, at most"),
) -> None:
    station = ws.app.state.station
    slot = station.state
    shared = station.telemetry_json
    min_interval_s = 1.0 / max_rate
    await ws.accept()
    # Held and cancelled below: it only exists to notice the client leaving while idle.
    watcher = asyncio.ensure_future(_until_disconnect(ws))
    version = 0
    next_send = 0.0
    try:
        while not watcher.done():
            current = await slot.wait_newer(version, timeout=_IDLE_CHECK_S)
            if slot.closed:
                break
            if current is None or current.version <= version:
                continue
            delay = next_send - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)
                current = slot.get() or current  # whatever is newest after the pause
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
