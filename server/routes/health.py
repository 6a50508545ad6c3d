"""Liveness: is the station up and are its background tasks alive."""

from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel

from server import __version__

router = APIRouter(tags=["health"])


class Health(BaseModel):
    ok: bool
    version: str
    failed_tasks: dict[str, str]


@router.get("/api/health", response_model=Health, summary="Is the station up")
async def get_health(request: Request) -> Health:
    station = request.app.state.station
    return Health(
        ok=station.tasks.healthy, version=__version__, failed_tasks=station.tasks.failures
    )
