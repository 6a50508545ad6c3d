"""`Spawn`: how a part starts a named background coroutine without knowing who supervises
it. The station passes `server.tasks.TaskSupervisor.spawn`, which logs and records a
task's failure; a part used on its own may pass `asyncio.create_task` wrapped alike."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine
from typing import Any

Spawn = Callable[[str, Coroutine[Any, Any, Any]], asyncio.Task[Any]]
