"""Named, supervised background tasks: none of their exceptions vanish.

Every long-running coroutine of the station runs through `TaskSupervisor.spawn`,
which keeps a reference, logs a crash with the task's name, records it for
`/api/health` and the systemd watchdog, and cancels everything at shutdown. A thread
that can die (the MAVLink link's) is watched the same way through `watch`.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Coroutine
from typing import Any

log = logging.getLogger(__name__)


class TaskSupervisor:
    def __init__(self) -> None:
        self._tasks: dict[str, asyncio.Task[Any]] = {}
        self._died: dict[str, str] = {}  # task name -> what killed it
        self._probes: dict[str, Callable[[], str | None]] = {}

    def spawn(self, name: str, coro: Coroutine[Any, Any, Any]) -> asyncio.Task[Any]:
        if name in self._tasks and not self._tasks[name].done():
            coro.close()
            raise RuntimeError(f"Task '{name}' is already running.")
        task = asyncio.create_task(coro, name=name)
        self._tasks[name] = task
        task.add_done_callback(self._on_done)
        return task

    def _on_done(self, task: asyncio.Task[Any]) -> None:
        if task.cancelled():
            return
        exc = task.exception()
        if exc is not None:
            self._died[task.get_name()] = f"{type(exc).__name__}: {exc}"
            log.error("background task %r died", task.get_name(), exc_info=exc)

    def watch(self, name: str, probe: Callable[[], str | None]) -> None:
        """Count `probe()` (what killed a thread, None while it is well) as a failure."""
        self._probes[name] = probe

    @property
    def failures(self) -> dict[str, str]:
        """Every supervised task or watched thread that died -> what killed it."""
        failed = dict(self._died)
        for name, probe in self._probes.items():
            if (why := probe()) is not None:
                failed[name] = why
        return failed

    @property
    def healthy(self) -> bool:
        return not self.failures

    async def cancel(self, task: asyncio.Task[Any]) -> None:
        """Cancel one task and wait until it has ended (before what it uses is stopped)."""
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)

    async def aclose(self) -> None:
        tasks = [t for t in self._tasks.values() if not t.done()]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        self._tasks.clear()
