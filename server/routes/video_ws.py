"""`WS /ws/video`: a page's live camera frames over one connection.

A browser gives a host six HTTP/1.1 connections, and each MJPEG `<img>` holds one for
good: two pilot pages and goggles used them all, and every page's `/api` requests queued
behind the streams. WebSockets are not counted against that limit, so each page takes
its cameras here, on one socket, and its `/api` requests keep the HTTP connections.

The client says which cameras it shows, whenever that changes:

    {"subscribe": ["front", "bottom"]}   only these from now on ([] for none)
    {"max_fps": 5}                       each camera at most this often (null: as it comes)
    {"ack": n}                           n messages handled so far (see `?ack=`)

and receives one binary message per frame of a subscribed camera (built once per frame
and shared by every client, `server.video_fanout.ws_message`): a 2-byte big-endian
header length, the JSON header {"camera", "seq", "t" (capture time, Unix s), "signal"}
and the camera's JPEG, unchanged. A camera nobody shows is not sent (and its fan-out
pump stops when no viewer of any kind is left).

Latest frame wins, as for the MJPEG viewers: the send happens in the client's own
coroutine; a client that is slow to read sits in its send and then gets each camera's
newest frame, skipping the ones it missed. `?ack=N` bounds what sits in socket buffers
(which would otherwise hold seconds of video for a slow reader): at most N messages are
unacknowledged; the pages use `?ack=4` and acknowledge, in their animation frames,
every second frame they paint or skip, so a page the browser gives few animation frames
(a background tab) is sent few frames. A page whose animation frames starve (a tab that
reads as visible but is not drawn: the browser gives it one a second) asks for
`max_fps` and draws each frame as it comes, so the few frames it is sent are fresh.

Host and Origin are checked by the guard (server/guard.py) as for every WebSocket; the
connection takes one place among the video clients (server/client_limits.py).
"""

from __future__ import annotations

import asyncio
import contextlib
import math

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from fpv_station.server.errors import Unavailable, deny_websocket
from fpv_station.server.guard import loads_message
from fpv_station.server.station import Station
from fpv_station.server.ws_acks import ack_of, ack_window_query, read_until_disconnect

router = APIRouter(tags=["video"])
# A subscription or an ack is a few bytes (server/listen.py closes the socket with 1009
# on a larger frame, before reading it).
MAX_FRAME_BYTES = 1024
# The slowest pace a client can ask for: a camera sent at least this often is still live.
MIN_PACED_FPS = 0.5


class _VideoClient:
    """What one page asked for, and how many of its messages it has handled."""

    def __init__(self, known: set[str]) -> None:
        self.known = known
        self.cameras: set[str] = set()
        self.acked = 0
        self.interval_s = 0.0  # between two frames of a camera, at least (0: unpaced)
        self.gone = False
        self.wake = asyncio.Event()

    def note(self, text: str | None) -> None:
        if not text:
            return
        try:
            msg = loads_message(text)
        except ValueError:
            return
        if not isinstance(msg, dict):
            return
        subscribe = msg.get("subscribe")
        if isinstance(subscribe, list):
            self.cameras = {c for c in subscribe if isinstance(c, str) and c in self.known}
        if "max_fps" in msg:
            self.interval_s = interval_of(msg["max_fps"])
        ack = ack_of(msg)
        if ack is not None and ack > self.acked:
            self.acked = ack
        self.wake.set()

    async def read_until_disconnect(self, ws: WebSocket) -> None:
        try:
            await read_until_disconnect(ws, self.note)
        finally:
            self.gone = True
            self.wake.set()


def interval_of(max_fps: object) -> float:
    """The time between two frames of a camera that `{"max_fps": x}` asks for: 0 (as the
    frames come) for null or anything but a positive finite number; at most the
    interval of MIN_PACED_FPS."""
    if isinstance(max_fps, bool) or not isinstance(max_fps, int | float):
        return 0.0
    try:
        fps = float(max_fps)
    except OverflowError:  # an integer beyond any float
        return 0.0
    if not math.isfinite(fps) or fps <= 0:
        return 0.0
    return 1.0 / max(fps, MIN_PACED_FPS)


@router.websocket("/ws/video")
async def ws_video(
    ws: WebSocket,
    ack: int = ack_window_query('{"ack": n} says n messages were handled'),
) -> None:
    station = ws.app.state.station
    try:
        with station.client_limits.video.slot():
            await _serve_video(ws, station, ack)
    except Unavailable as exc:
        await deny_websocket(ws, 503, "Unavailable", exc.message)


async def _serve_video(ws: WebSocket, station: Station, window: int) -> None:
    fanouts = station.video_fanouts
    await ws.accept()
    client = _VideoClient(set(fanouts))
    watcher = asyncio.ensure_future(client.read_until_disconnect(ws))
    held: dict[str, contextlib.ExitStack] = {}
    sent_version: dict[str, int] = {}
    served_at: dict[str, int] = {}  # the message count when each camera was last sent
    sent_at: dict[str, float] = {}  # the loop's time when each camera was last sent
    sent = 0
    loop = asyncio.get_running_loop()
    try:
        while not client.gone and not any(f.closed for f in fanouts.values()):
            for name in set(held) - client.cameras:  # no longer shown: stop sending
                held.pop(name).close()
                sent_version.pop(name, None)
            for name in client.cameras - set(held):
                stack = contextlib.ExitStack()
                fanout = fanouts[name]
                camera = station.cameras[name]
                stack.enter_context(fanout.listen(client.wake, camera.watching()))
                held[name] = stack
            new = [n for n in held if fanouts[n].version > sent_version.get(n, 0)]
            # A paced client: a camera is due once its interval has passed.
            next_at = {n: sent_at.get(n, -math.inf) + client.interval_s for n in new}
            now = loop.time()
            due = [n for n in new if next_at[n] <= now]
            if not due or (window and sent - client.acked >= window):
                client.wake.clear()  # nothing awaited since the look: no wake-up is lost
                paced = [next_at[n] - now for n in new if n not in due]
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(client.wake.wait(), min(paced) if paced else None)
                continue
            # The camera served longest ago first: one camera cannot starve another.
            name = min(due, key=lambda n: served_at.get(n, -1))
            fanout = fanouts[name]
            version, message = fanout.version, fanout.ws_message()
            await ws.send_bytes(message)
            sent_version[name], served_at[name], sent_at[name] = version, sent, now
            sent += 1
    except (WebSocketDisconnect, RuntimeError, ConnectionError):
        pass  # the client went away mid-send
    finally:
        for stack in held.values():
            stack.close()
        watcher.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await watcher
        with contextlib.suppress(RuntimeError, WebSocketDisconnect):
            await ws.close()
