"""`GET /api/status`: the vehicle link's health, the vehicle state, and versions."""

from __future__ import annotations

import platform

from fastapi import APIRouter, Request
from pydantic import BaseModel

from companion.link_health import LinkHealth
from companion.vehicle_state import VehicleState
from server import __version__

router = APIRouter(tags=["telemetry"])


class Versions(BaseModel):
    fpv_station: str
    python: str
    pymavlink: str
    fastapi: str


class StatusReply(BaseModel):
    source: str  # the configured MAVLink source (connection string, "sim" or "none")
    link: LinkHealth | None  # None when there is no vehicle link (source "none")
    state_version: int  # grows by one per state change; 0 before the first
    state: VehicleState | None  # None before the first state
    versions: Versions


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
    return StatusReply(
        source=station.settings.link.source,
        link=station.link.health() if station.link is not None else None,
        state_version=current.version if current is not None else 0,
        state=current.value if current is not None else None,
        versions=_versions(),
    )
