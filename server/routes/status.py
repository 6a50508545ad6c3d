"""`GET /api/status`: the vehicle link's health, the vehicle state, and versions."""

from __future__ import annotations

import functools
import platform

from fastapi import APIRouter, Request
from pydantic import BaseModel

from fpv_station.companion.link_health import LinkHealth
from fpv_station.companion.timesync import VehicleClock
from fpv_station.companion.vehicle_state import VehicleState
from fpv_station.server import __version__
from fpv_station.server.routes.control import ControlLevel, control_level

router = APIRouter(tags=["telemetry"])


class Versions(BaseModel):
    fpv_station: str
    python: str
    pymavlink: str
    fastapi: str


class RecordingNow(BaseModel):
    recording: bool  # a session is being recorded
    # The vehicle is armed and no session records it (a refused start being retried, a
    # session cut short, or recording off): the pages show NOT RECORDING.
    not_recording: bool


class StatusReply(BaseModel):
    source: str  # the configured MAVLink source (connection string, "sim" or "none")
    link: LinkHealth | None  # None when there is no vehicle link (source "none")
    # What the pages may command (WS /ws/control): "twin" sticks and every command,
    # "emergency" a real vehicle's Disarm, Land and RTL, "none" nothing (no live link)
    control: ControlLevel = "none"
    # The vehicle's boot clock on the station's monotonic clock (TIMESYNC), or why not
    vehicle_clock: VehicleClock | None = None
    recording: RecordingNow | None = None  # None: the station has no recorder
    state_version: int  # grows by one per state change; 0 before the first
    state: VehicleState | None  # None before the first state
    versions: Versions


@functools.cache  # read once: each read opens package metadata files (none under EMFILE)
def _versions() -> Versions:
    from importlib.metadata import PackageNotFoundError, version

    def v(pkg: str) -> str:
        try:
            return version(pkg)
        except PackageNotFoundError:
            return "unknown"

    return Versions(
        fpv_station=__version__,
        python=platform.python_version(),
        pymavlink=v("pymavlink"),
        fastapi=v("fastapi"),
    )


@router.get("/api/status", response_model=StatusReply, summary="Link health and vehicle state")
async def get_status(request: Request) -> StatusReply:
    station = request.app.state.station
    current = station.state.get()
    recorder = station.recorder
    rec = recorder.status() if recorder is not None else None
    return StatusReply(
        source=station.settings.link.source,
        link=station.link.health() if station.link is not None else None,
        control=control_level(station),
        vehicle_clock=station.link.timesync.report() if station.link is not None else None,
        recording=None
        if rec is None
        else RecordingNow(recording=rec.recording, not_recording=rec.not_recording),
        state_version=current.version if current is not None else 0,
        state=current.value if current is not None else None,
        versions=_versions(),
    )
