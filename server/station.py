"""The running station: every service the app serves from, built in the app's lifespan.

Nothing here opens hardware at import time; `open_station` builds the services from
the settings, starts them in dependency order and stops them in reverse.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from typing import Any

from server.settings import Settings
from server.tasks import TaskSupervisor


@dataclass
class Station:
    settings: Settings
    tasks: TaskSupervisor = field(default_factory=TaskSupervisor)
    # name -> companion.cameras.capture.Camera; readers use `.frames` (a Latest[Frame])
    cameras: dict[str, Any] = field(default_factory=dict)


@contextlib.asynccontextmanager
async def open_station(settings: Settings) -> AsyncIterator[Station]:
    station = Station(settings=settings)
    async with contextlib.AsyncExitStack() as stack:
        stack.push_async_callback(station.tasks.aclose)
        await _open_cameras(station, stack)
        yield station


async def _open_cameras(station: Station, stack: contextlib.AsyncExitStack) -> None:
    """Front and bottom cameras; after the twin, whose renderer the sim cameras use."""
    from companion.cameras.rig import CAMERA_NAMES, build_camera, start_cameras, stop_cameras

    cams = station.settings.cameras
    for name in CAMERA_NAMES:
        station.cameras[name] = build_camera(
            name,
            getattr(cams, name),
            link_source=station.settings.link.source,
            renderer=lambda: getattr(station, "twin", None),
            stall_s=cams.stall_s,
            retry_min_s=cams.retry_min_s,
            retry_max_s=cams.retry_max_s,
        )
    start_cameras(station.cameras.values())
    stack.push_async_callback(asyncio.to_thread, stop_cameras, list(station.cameras.values()))
