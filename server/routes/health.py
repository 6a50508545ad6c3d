"""Liveness: is the station up and are its background tasks alive."""

from __future__ import annotations

import asyncio
from typing import Literal

from fastapi import APIRouter, Request
from pydantic import BaseModel

from server import __version__

router = APIRouter(tags=["health"])


class Health(BaseModel):
    ok: bool  # up, and doing all it should (status "ok")
    status: Literal["ok", "degraded"]
    reasons: list[str]  # why degraded, in words
    version: str
    failed_tasks: dict[str, str]
    asyncio_tasks: int  # all tasks on the event loop: flat under steady load (soak)


@router.get("/api/health", response_model=Health, summary="Is the station up and well")
async def get_health(request: Request) -> Health:
    station = request.app.state.station
    reasons = [f"background task {n} died: {why}" for n, why in station.tasks.failures.items()]
    recorder = station.recorder
    if recorder is not None and recorder.failure is not None:
        reasons.append(f"recording failed: {recorder.failure}")
    if recorder is not None and recorder.last_error is not None:
        reasons.append(f"recording cannot start: {recorder.last_error}")
    return Health(
        ok=not reasons,
        status="degraded" if reasons else "ok",
        reasons=reasons,
        version=__version__,
        failed_tasks=station.tasks.failures,
        asyncio_tasks=len(asyncio.all_tasks()),
    )
