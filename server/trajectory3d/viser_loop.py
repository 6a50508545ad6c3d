"""Every change to a viser scene or GUI runs on that viser server's own event-loop thread.

viser buffers each outgoing message and wakes its senders with an `asyncio.Event` of its
own loop, and it sets that event directly from the thread that made the change. Set from
another thread, the event walks its waiters (one per connected viewer) while viser's loop
adds and removes them: "deque mutated during iteration", and the panel's task dies. So the
station never changes a scene from its own loop or a worker thread: it hands the whole
update to viser's loop, one hop per update (`on_viser_loop` from the station's loop,
`on_viser_loop_blocking` from a worker thread).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
from collections.abc import Callable
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:
    import viser

T = TypeVar("T")


def _submit(server: viser.ViserServer, fn: Callable[[], T]) -> concurrent.futures.Future[T]:
    loop = server.get_event_loop()
    if loop.is_closed() or not loop.is_running():
        raise RuntimeError("The viser server has stopped.")

    async def call() -> T:
        return fn()

    return asyncio.run_coroutine_threadsafe(call(), loop)


async def on_viser_loop(server: viser.ViserServer, fn: Callable[[], T]) -> T:
    """Run `fn()` on `server`'s event-loop thread; the caller's loop awaits its result
    (or its exception) without blocking."""
    return await asyncio.wrap_future(_submit(server, fn))


def on_viser_loop_blocking(server: viser.ViserServer, fn: Callable[[], T]) -> T:
    """Run `fn()` on `server`'s event-loop thread and wait for it: for worker threads
    only, never from an event loop."""
    return _submit(server, fn).result()
