"""The running station: every service the app serves from, built in the app's lifespan.

Nothing here opens hardware at import time; `open_station` builds the services from
the settings, starts them in dependency order and stops them in reverse.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

from companion.latest import Latest
from companion.link import MavlinkLink
from companion.recording.recorder import Recorder
from companion.vehicle_state import VehicleState
from server.settings import Settings
from server.tasks import TaskSupervisor
from server.telemetry_json import SharedStateJson


@dataclass
class Station:
    settings: Settings
    tasks: TaskSupervisor = field(default_factory=TaskSupervisor)
    # The vehicle link (None for source "none") and its state slot. For "none" the slot
    # stays empty, so consumers need no special case: they simply never get a state.
    link: MavlinkLink | None = None
    state: Latest[VehicleState] = field(default_factory=Latest)
    telemetry_json: SharedStateJson = field(default_factory=SharedStateJson)
    recorder: Recorder | None = None


@contextlib.asynccontextmanager
async def open_station(settings: Settings) -> AsyncIterator[Station]:
    station = Station(settings=settings)
    async with contextlib.AsyncExitStack() as stack:
        stack.push_async_callback(station.tasks.aclose)

        # -- vehicle link ----------------------------------------------------------
        source = settings.link.source.strip()
        if source == "sim":
            # The twin section starts an embedded twin vehicle here, then points a
            # MavlinkLink at it over a loopback socket and sets station.link/state,
            # exactly as for a real vehicle below.
            pass
        elif source != "none":
            link = MavlinkLink(settings.link)
            link.start()
            stack.callback(link.stop)
            station.link = link
            station.state = link.state

        # -- recorder (after the link and cameras it records) -----------------------
        station.recorder = await _open_recorder(station, stack)
        yield station


async def _open_recorder(station: Station, stack: contextlib.AsyncExitStack) -> Recorder:
    from server.recording import open_recorder

    state = station.state
    cams = getattr(station, "cameras", None) or {}
    return await open_recorder(
        station.settings, stack, station.tasks.spawn, state,
        {name: cam.frames for name, cam in cams.items()},
        {name: getattr(cam, "fps", None) for name, cam in cams.items()},
        getattr(station, "link", None),
    )
