"""Flow control shared by the streaming WebSockets (`/ws/telemetry`, `/ws/video`).

A client asks for `?ack=N` (at most N messages unacknowledged; 0: no acks) and says what
it has handled with `{"ack": n}`; the route decides what n counts (a telemetry version,
a count of video messages). This module is the query parameter, the reading of n out of
a client's message, and the loop that reads what a client sends until it leaves.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any

from fastapi import Query, WebSocket, WebSocketDisconnect

# The largest window: a larger one would not bound a slow client's staleness.
MAX_ACK_WINDOW = 16


def ack_window_query(acknowledges: str) -> Any:
    """The `?ack=N` query parameter; `acknowledges` says what `{"ack": n}` means."""
    return Query(
        0,
        ge=0,
        le=MAX_ACK_WINDOW,
        description=f"0: no acks; N: at most N messages unacknowledged, {acknowledges}",
    )


def ack_of(message: object) -> int | None:
    """n of a client's parsed `{"ack": n}`; None when it carries no whole number."""
    ack = message.get("ack") if isinstance(message, dict) else None
    return ack if isinstance(ack, int) and not isinstance(ack, bool) else None


async def read_until_disconnect(ws: WebSocket, on_text: Callable[[str | None], None]) -> None:
    """Hand each frame's text (None for a binary frame) to `on_text` until the client
    leaves; returns then, or when the socket fails."""
    with contextlib.suppress(WebSocketDisconnect, RuntimeError):
        while True:
            msg = await ws.receive()
            if msg["type"] == "websocket.disconnect":
                return
            on_text(msg.get("text"))
