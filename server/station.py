"""The running station: every service the app serves from, built in the app's lifespan.

Nothing here opens hardware at import time; `open_station` builds the services from
the settings, starts them in dependency order and stops them in reverse.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from server.settings import Settings
from server.tasks import TaskSupervisor

if TYPE_CHECKING:
    from server.trajectory3d.service import Trajectory3D


@dataclass
class Station:
    settings: Settings
    tasks: TaskSupervisor = field(default_factory=TaskSupervisor)
    trajectory3d: Trajectory3D | None = None  # the viser panel; None with --no-3d


@contextlib.asynccontextmanager
async def open_station(settings: Settings) -> AsyncIterator[Station]:
    station = Station(settings=settings)
    async with contextlib.AsyncExitStack() as stack:
        stack.push_async_callback(station.tasks.aclose)
        if settings.viser.enabled:
            await _start_trajectory3d(station, stack)
        yield station


async def _start_trajectory3d(station: Station, stack: contextlib.AsyncExitStack) -> None:
    from companion.latest import Latest
    from server.trajectory3d.field import default_field
    from server.trajectory3d.service import open_trajectory3d

    # The vehicle state slot comes from the link; without a link the panel shows the field.
    state = getattr(station, "state", None) or Latest()
    s = station.settings
    field = default_field() if s.link.source == "sim" else None
    service = await open_trajectory3d(s.viser, state, s.server.host, field)
    station.trajectory3d = service
    # viser's stop joins its thread: keep that wait off the event loop.
    stack.push_async_callback(asyncio.to_thread, service.stop)
    station.tasks.spawn("trajectory3d", service.run())
