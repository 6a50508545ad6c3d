"""Fan one camera's frames out to every viewer on the event loop.

The capture thread wakes one waiter per camera (this pump), not one per viewer: the
pump takes each new frame from the camera's `Latest[Frame]` and wakes the viewers with
in-loop events (no thread hop, no syscall per viewer). Each kind of message is built
once per frame, when the first viewer of that kind asks for it, and shared: the MJPEG
multipart part (`part()`) and the binary WebSocket message of `/ws/video`
(`ws_message()`). A viewer that is busy writing misses events and, when it comes back,
gets the newest message: latest value wins, nothing queues. The pump runs only while
someone watches (pikvm's streamer rule) and is supervised by the station's task
supervisor.
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from typing import Any

import orjson

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


def ws_message(camera: str, frame: Frame) -> bytes:
    """One binary `/ws/video` message: a 2-byte big-endian header length, the header
    (JSON: camera, seq, capture time `t` in Unix seconds, signal) and the JPEG."""
    head = orjson.dumps(
        {"camera": camera, "seq": frame.seq, "t": round(frame.t_wall, 6), "signal": frame.signal}
    )
    return b"".join((struct.pack(">H", len(head)), head, frame.jpeg))


class FrameFanout:
    """The newest multipart part of one camera, with an event that fires per new frame.
    `spawn` starts its pump (the station's supervised `tasks.spawn`)."""

    def __init__(self, name: str, frames: Latest[Frame], spawn: Spawn) -> None:
        self.name = name
        self.frames = frames
        self._spawn = spawn
        self.version = 0
        self.frame: Frame | None = None
        self._built: dict[str, tuple[int, bytes]] = {}  # kind -> (version, message)
        self.viewers = 0
        self._listeners: set[asyncio.Event] = set()  # /ws/video clients' wake-ups
        self._event = asyncio.Event()
        self._task: asyncio.Task[Any] | None = None
        self.closed = False  # the server is shutting down: every stream ends

    def close(self) -> None:
        """End every viewer's stream after the part it is sending (server shutdown), so
        that their responses complete instead of being cancelled mid-stream."""
        self.closed = True
        self._event.set()
        self._wake_listeners()

    def _wake_listeners(self) -> None:
        for wake in self._listeners:
            wake.set()

    def _message(self, kind: str, build: Callable[[Frame], bytes]) -> bytes:
        """The newest frame as `kind`, built once per frame for every viewer."""
        built = self._built.get(kind)
        if built is not None and built[0] == self.version:
            return built[1]
        if self.frame is None:
            return b""
        message = build(self.frame)
        self._built[kind] = (self.version, message)
        return message

    def part(self) -> bytes:
        """The newest frame's MJPEG multipart part."""
        return self._message("mjpeg", multipart_part)

    def ws_message(self) -> bytes:
        """The newest frame's binary `/ws/video` message."""
        return self._message("ws", lambda frame: ws_message(self.name, frame))

    @contextlib.contextmanager
    def listen(
        self, wake: asyncio.Event, watching: contextlib.AbstractContextManager[Any]
    ) -> Iterator[None]:
        """Count a `/ws/video` client as a viewer while the block runs: `wake` is set on
        every new frame (and when the camera or the server closes). It is set at once,
        so that a frame the camera already has is sent without waiting for the next."""
        self.viewers += 1
        self._listeners.add(wake)
        try:
            with watching:
                self._ensure_pump()
                wake.set()
                yield
        finally:
            self._listeners.discard(wake)
            self.viewers -= 1

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
                    self.frame, self.version = item.value, item.version
                    self._wake_listeners()
                # A new part, or a silence: either way the viewers wake (after a silence,
                # to see whether their clients are still there). One timer here instead
                # of one per viewer per frame.
                event, self._event = self._event, asyncio.Event()
                event.set()
        finally:
            self._event.set()  # release the viewers (camera closed, nobody left, cancelled)
            self._wake_listeners()

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
                        yield self.part()
                        continue
                    self._ensure_pump()
                    await self._event.wait()
                    if self.version <= sent and await is_disconnected():
                        return  # woken by a silence, and the client has gone
        finally:
            self.viewers -= 1
