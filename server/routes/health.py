"""Liveness: is the station up and are its background tasks alive."""

from __future__ import annotations

import asyncio
import time
from typing import TYPE_CHECKING, Literal

from fastapi import APIRouter, Request
from pydantic import BaseModel

from fpv_station.companion.recording.recorder import NOT_RECORDING_AFTER_S
from fpv_station.companion.recording.session_clock import choose_session_clock
from fpv_station.companion.system_clock import clock_synchronised
from fpv_station.server import __version__

if TYPE_CHECKING:
    from fpv_station.server.station import Station

router = APIRouter(tags=["health"])


class ClockReport(BaseModel):
    """The time a session starting now would be named by (a Pi has no real-time clock)."""

    station_synced: bool | None  # the kernel's answer (adjtimex); None: unknown
    vehicle_offset_s: float | None  # the vehicle's GPS time minus the station's clock
    sessions_use: str  # "station", "vehicle" (its GPS time) or "source" (a replay's own)
    reason: str


class Health(BaseModel):
    ok: bool  # up, and doing all it should (status "ok")
    status: Literal["ok", "degraded"]
    reasons: list[str]  # why degraded, in words
    version: str
    failed_tasks: dict[str, str]
    asyncio_tasks: int  # all tasks on the event loop: flat under steady load (soak)
    clock: ClockReport


@router.get("/api/health", response_model=Health, summary="Is the station up and well")
async def get_health(request: Request) -> Health:
    station = request.app.state.station
    failed = station.tasks.failures
    reasons = [f"background task {n} died: {why}" for n, why in failed.items()]
    recorder = station.recorder
    if recorder is not None and recorder.failure is not None:
        reasons.append(f"recording failed: {recorder.failure}")
    if recorder is not None and recorder.last_error is not None:
        reasons.append(f"recording cannot start: {recorder.last_error}")
    # A flight the station should be recording (recording on arming) and is not.
    auto = recorder is not None and recorder.options.auto_record_on_arm
    unrecorded = recorder.armed_unrecorded_s() if auto else None
    if unrecorded is not None and unrecorded >= NOT_RECORDING_AFTER_S:
        reasons.append(f"the vehicle has been armed for {unrecorded:.0f} s without a recording")
    return Health(
        ok=not reasons,
        status="degraded" if reasons else "ok",
        reasons=reasons,
        version=__version__,
        failed_tasks=failed,
        asyncio_tasks=len(asyncio.all_tasks()),
        clock=_clock_report(station),
    )


def _clock_report(station: Station) -> ClockReport:
    current = station.state.get()
    replay = station.link is not None and station.link.clock.own
    choice = choose_session_clock(
        time.time(),
        time.monotonic(),
        None if replay else clock_synchronised(),
        # a replay's GPS time is on the log's clock, not this one: no offset to show
        None if replay or current is None else current.value.utc,
        replay=replay,
        max_disagree_s=station.settings.recording.clock_max_disagree_s,
    )
    vehicle = choice.vehicle_start_utc
    return ClockReport(
        station_synced=choice.station_synced,
        vehicle_offset_s=None if vehicle is None else round(vehicle - choice.station_start_wall, 3),
        sessions_use=choice.used,
        reason=choice.reason,
    )
