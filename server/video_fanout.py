"""Fan one camera's frames out to every MJPEG viewer on the event loop.

The capture thread wakes one waiter per camera (this pump), not one per viewer: the
pump takes each new frame from the camera's `Latest[Frame]`, builds its multipart part
once, and wakes the viewers with an in-loop event (no thread hop, no syscall per
viewer). A viewer that is busy writing misses events and, when it comes back, gets the
newest part: latest value wins, nothing queues. The pump runs only while someone
watches (pikvm's streamer rule) and is supervised by the station's task supervisor.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any

from fpv_station.companion.latest import Latest
from fpv_station.companion.video_frame import Frame
from fpv_station.core.spawn import Spawn

BOUNDARY = "fpvframe"
# While a camera sends nothing (a `none` camera, a stuck source), the pump wakes its
# viewers this often to check their connections, and looks whether anyone still watches.
_SILENCE_CHECK_S = 2.0


def frame_time_header(frame: Frame) -> str:
    """Capture time as Unix seconds with microseconds."""
    return f"{frame.t_wall:.6f}"


OPENING = f"--{BOUNDARY}\r\n".encode("ascii")
_CLOSING = b"\r\n" + OPENING


def multipart_part(frame: Frame) -> bytes:
    """One part, closed by the next boundary right away: a browser shows a part only
    once it sees the boundary after it, so a trailing boundary saves a frame interval
    of latency (and lets a camera's last frame show at all)."""
    head = (
        f"Content-Type: image/jpeg\r\nContent-Length: {len(frame.jpeg)}\r\n"
        f"X-Frame-Seq: {frame.seq}\r\nX-Frame-Time: {frame_time_header(frame)}\r\n"
        f"X-Frame-Signal: {int(frame.signal)}\r\n\r\n"
    ).encode("ascii")
    return b"".join((head, frame.jpeg, _CLOSING))  # one copy of the JPEG, not three


class FrameFanout:
    """The newest multipart part of one camera, with an event that fires per new frame.
    `spawn` starts its pump (the station's supervised `tasks.spawn`)."""

    def __init__(self, name: str, frames: Latest[Frame], spawn: Spawn) -> None:
        self.name = name
        self.frames = frames
        self._spawn = spawn
        self.version = 0
        self.part = b""
        self.viewers = 0
        self._event = asyncio.Event()
        self._task: asyncio.Task[Any] | None = None
        self.closed = False  # the server is shutting down: every stream ends

    def close(self) -> None:
        """End every viewer's stream after the part it is sending (server shutdown), so
        that their responses complete instead of being cancelled mid-stream."""
        self.closed = True
        self._event.set()

    def _ensure_pump(self) -> None:
        if self._task is None or self._task.done():
            # A fresh event, set synchronously: the previous pump's final set() must not
            # let viewers spin on a set event before the new pump has run.
            self._event = asyncio.Event()
            self._task = self._spawn(f"video-fanout-{self.name}", self._pump())

    async def _pump(self) -> None:
        try:
            while not self.frames.closed and not self.closed and self.viewers > 0:
                item = await self.frames.wait_newer(self.version, timeout=_SILENCE_CHECK_S)
                if item is not None and item.version > self.version:
                    self.part, self.version = multipart_part(item.value), item.version
                # A new part, or a silence: either way the viewers wake (after a silence,
                # to see whether their clients are still there). One timer here instead
                # of one per viewer per frame.
                event, self._event = self._event, asyncio.Event()
                event.set()
        finally:
            self._event.set()  # release the viewers (camera closed, nobody left, cancelled)

    async def stream(
        self,
        watching: contextlib.AbstractContextManager[Any],
        is_disconnected: Callable[[], Awaitable[bool]],
    ) -> AsyncIterator[bytes]:
        """The parts one viewer receives, newest first, until the camera closes.

        A disconnect shows as an error on the next write; while a camera sends nothing
        (a `none` camera, a stuck source) the pump wakes the viewer every
        `_SILENCE_CHECK_S` to ask `is_disconnected`.
        """
        self.viewers += 1
        try:
            with watching:
                yield OPENING
                sent = 0
                while not self.frames.closed and not self.closed:
                    if self.version > sent:
                        sent = self.version
                        yield self.part
                        continue
                    self._ensure_pump()
                    await self._event.wait()
                    if self.version <= sent and await is_disconnected():
                        return  # woken by a silence, and the client has gone
        finally:
            self.viewers -= 1
