"""The running station: every service the app serves from, built in the app's lifespan.

Nothing here opens hardware at import time; `open_station` builds the services from
the settings, starts them in dependency order and stops them in reverse.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

from server.settings import Settings
from server.tasks import TaskSupervisor


@dataclass
class Station:
    settings: Settings
    tasks: TaskSupervisor = field(default_factory=TaskSupervisor)


@contextlib.asynccontextmanager
async def open_station(settings: Settings) -> AsyncIterator[Station]:
    station = Station(settings=settings)
    async with contextlib.AsyncExitStack() as stack:
        stack.push_async_callback(station.tasks.aclose)
        yield station
