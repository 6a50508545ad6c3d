"""The one mechanism that hands data from I/O threads to asyncio: a latest-value slot.

A producer thread (MAVLink reader, camera capture, the twin) calls `publish(value)`;
consumers read the newest value with `get()` or wait for a newer one with
`await wait_newer(version)`. Nothing queues: a slow consumer skips straight to the
newest value, so no buffer grows and no consumer delays another (viser's
"latest value wins", pikvm's streamer pattern).

Waking the waiters goes through `loop.call_soon_threadsafe`, so a thread never touches
the event loop's objects directly. `publish` is cheap when nobody waits.

A consumer that must see every value, not the newest (the recorder takes every camera
frame), registers a publish listener instead: called in the producer's thread with each
value, it must only hand the value to a bounded buffer and return. A listener that only
has to tell the loop "look now" (a flag changed, a viewer came) calls `Wakeup.wake`.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class Versioned(Generic[T]):
    """A value and its version: versions start at 1 and grow by one per publish."""

    version: int
    value: T


class Latest(Generic[T]):
    """Thread-safe latest-value slot with async waiting for a newer version."""

    def __init__(self, initial: T | None = None) -> None:
        self._lock = threading.Lock()
        self._current: Versioned[T] | None = Versioned(1, initial) if initial is not None else None
        self._waiters: list[tuple[asyncio.AbstractEventLoop, asyncio.Future[None]]] = []
        self._closed = False
        self._listeners: tuple[Callable[[T], None], ...] = ()

    @property
    def version(self) -> int:
        """The version of the newest value, 0 before the first publish."""
        current = self._current
        return current.version if current is not None else 0

    def get(self) -> Versioned[T] | None:
        """The newest value with its version, or None before the first publish."""
        return self._current

    def current(self) -> T:
        """The newest value, for a slot that always holds one (made with an initial value);
        LookupError before the first publish."""
        current = self._current
        if current is None:
            raise LookupError("nothing is published in this slot yet")
        return current.value

    def publish(self, value: T) -> int:
        """Store `value` as the newest one and wake every waiter. Callable from any thread."""
        with self._lock:
            version = self.version + 1
            self._current = Versioned(version, value)
            waiters, self._waiters = self._waiters, []
            listeners = self._listeners
        for listener in listeners:
            listener(value)
        _wake_waiters(waiters)
        return version

    def add_listener(self, listener: Callable[[T], None]) -> None:
        """Call `listener(value)` in the publisher's thread on every publish; it must not
        block (hand the value to a bounded buffer)."""
        with self._lock:
            self._listeners = (*self._listeners, listener)

    def remove_listener(self, listener: Callable[[T], None]) -> None:
        """Remove a listener added before. Compared by equality, not identity: each
        `obj.method` access makes a new bound method, equal to the one that was added."""
        with self._lock:
            self._listeners = tuple(x for x in self._listeners if x != listener)

    def close(self) -> None:
        """Wake every waiter for good; later waits return at once."""
        with self._lock:
            self._closed = True
            waiters, self._waiters = self._waiters, []
        _wake_waiters(waiters)

    @property
    def closed(self) -> bool:
        return self._closed

    async def wait_newer(self, version: int, timeout: float | None = None) -> Versioned[T] | None:  # noqa: ASYNC109
        """Wait until a value newer than `version` exists and return it.

        Returns the current value (possibly not newer) on timeout or when the slot is
        closed; callers compare versions. Returns None only if nothing was ever published.
        """
        with self._lock:
            current = self._current
            if self._closed or (current is not None and current.version > version):
                return current
            loop = asyncio.get_running_loop()
            fut: asyncio.Future[None] = loop.create_future()
            self._waiters.append((loop, fut))
        try:
            await wait_resolved(fut, timeout)
        finally:
            # On timeout or cancellation the waiter must leave the list, or a consumer
            # that polls with a timeout while nothing is published would grow it.
            with self._lock:
                try:
                    self._waiters.remove((loop, fut))
                except ValueError:
                    pass
        return self._current


async def wait_resolved(fut: asyncio.Future[None], timeout: float | None) -> None:  # noqa: ASYNC109
    """Wait until `fut` is resolved, or `timeout` seconds, whichever comes first; the
    caller looks at its own state afterwards. A timer that resolves the future, not
    asyncio.wait_for: that wraps each wait in a task of its own (Python 3.11), and the
    waits here run per client per message."""
    timer = None
    if timeout is not None:
        timer = asyncio.get_running_loop().call_later(timeout, _wake, [fut])
    try:
        await fut
    finally:
        if timer is not None:
            timer.cancel()


class Wakeup:
    """A wake-up that any thread gives and one event-loop coroutine waits for: an
    `asyncio.Event` whose `wake` may be called from any thread, with one hop to the
    loop only while the coroutine waits. A `wake` stays set until `clear`, so a waiter
    that clears it, looks at what it watches and then waits misses none."""

    def __init__(self) -> None:
        self._set = False
        self._waiter: tuple[asyncio.AbstractEventLoop, asyncio.Future[None]] | None = None

    def wake(self) -> None:
        """Any thread: the current or the next `wait` returns."""
        self._set = True
        waiter = self._waiter
        if waiter is not None:
            wake_from_any_thread(*waiter)

    def clear(self) -> None:
        self._set = False

    async def wait(self, timeout: float | None = None) -> None:  # noqa: ASYNC109
        """Until `wake` (at once if it came since `clear`), or `timeout` seconds."""
        if self._set:
            return
        loop = asyncio.get_running_loop()
        fut = loop.create_future()
        self._waiter = (loop, fut)
        try:
            if not self._set:  # woken before the waiter was in place
                await wait_resolved(fut, timeout)
        finally:
            self._waiter = None


def wake_from_any_thread(loop: asyncio.AbstractEventLoop, *futs: asyncio.Future[None]) -> None:
    """Resolve `futs` on their `loop` from any thread, with one hop to that loop (a no-op
    for each one resolved already, and once that loop has closed: nothing waits any more)."""
    try:
        loop.call_soon_threadsafe(_wake, futs)
    except RuntimeError:
        pass


def _wake_waiters(waiters: list[tuple[asyncio.AbstractEventLoop, asyncio.Future[None]]]) -> None:
    # One call_soon_threadsafe per loop, not per waiter: each call writes to the loop's
    # self-pipe, and twenty WebSocket clients waiting on telemetry would mean twenty
    # syscalls per MAVLink packet.
    by_loop: dict[asyncio.AbstractEventLoop, list[asyncio.Future[None]]] = {}
    for loop, fut in waiters:
        by_loop.setdefault(loop, []).append(fut)
    for loop, futs in by_loop.items():
        wake_from_any_thread(loop, *futs)


def _wake(futs: Iterable[asyncio.Future[None]]) -> None:
    for fut in futs:
        if not fut.done():
            fut.set_result(None)
