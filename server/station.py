"""The running station: every service the app serves from, built in the app's lifespan.

Nothing here opens hardware at import time; `open_station` builds the services from
the settings, starts them in dependency order and stops them in reverse.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

from companion.recording.recorder import Recorder
from server.settings import Settings
from server.tasks import TaskSupervisor


@dataclass
class Station:
    settings: Settings
    tasks: TaskSupervisor = field(default_factory=TaskSupervisor)
    recorder: Recorder | None = None


@contextlib.asynccontextmanager
async def open_station(settings: Settings) -> AsyncIterator[Station]:
    station = Station(settings=settings)
    async with contextlib.AsyncExitStack() as stack:
        stack.push_async_callback(station.tasks.aclose)
        station.recorder = await _open_recorder(station, stack)
        yield station


async def _open_recorder(station: Station, stack: contextlib.AsyncExitStack) -> Recorder:
    # Until the link and cameras are built here, record an empty state and no camera.
    from companion.latest import Latest
    from companion.vehicle_state import VehicleState
    from server.recording import open_recorder

    state = getattr(station, "state", None) or Latest(VehicleState())
    cams = getattr(station, "cameras", None) or {}
    return await open_recorder(
        station.settings, stack, station.tasks.spawn, state,
        {name: cam.frames for name, cam in cams.items()},
        {name: getattr(cam, "fps", None) for name, cam in cams.items()},
        getattr(station, "link", None),
    )
