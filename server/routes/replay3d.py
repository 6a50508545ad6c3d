"""The replay's 3D panel: which sessions it shows and the instant of the time slider.

Both endpoints change only what the replay panel draws, never recorded data; but the scene
is shared by every viewer of the replay panel (the last page to load or scrub wins), so
they need the control token like every change others see (server/auth.py). The scene is
changed on its viser server's own loop thread (server/trajectory3d/viser_loop.py).
"""

from __future__ import annotations

import asyncio
import functools
import math

from fastapi import APIRouter, Depends, Request
from pydantic import BaseModel, Field

from fpv_station.server.auth import require_control_token
from fpv_station.server.errors import BadRequest, Unavailable
from fpv_station.server.routes.recording import get_recorder
from fpv_station.server.routes.trajectory import load_trajectory, reference_param
from fpv_station.server.station import start_3d_panels
from fpv_station.server.trajectory3d.replay import Align
from fpv_station.server.trajectory3d.viser_loop import on_viser_loop

router = APIRouter(tags=["trajectory"])


class Replay3DLoad(BaseModel):
    session: str = Field(min_length=1, max_length=200)
    overlay: str | None = None  # a second session drawn in another colour
    align: Align = "none"  # as GET /api/sessions/{id}/trajectory, applied to both
    reference: str | None = None  # LAT,LON put on +x


class Replay3DTime(BaseModel):
    t_s: float = Field(
        description="the instant on the session clock (telemetry.csv's and frames.csv's "
        "t_s: seconds since the session started), as the replay page's slider"
    )


class Replay3DState(BaseModel):
    port: int
    session: str | None
    overlay: str | None
    t_s: float  # session clock
    duration_s: float | None  # session clock of the session's last row, fix or frame
    segments: int  # path segments drawn for the session


async def _service(request: Request):
    await start_3d_panels(request.app.state.station)  # a first visit may come here
    service = request.app.state.station.replay3d
    if service is None or service.server is None:
        raise Unavailable("The 3D replay panel is not running (--no-3d).")
    return service


def _state(service) -> Replay3DState:
    a, b = service.primary, service.overlay
    return Replay3DState(
        port=service.port,
        session=a.id if a else None,
        overlay=b.id if b else None,
        t_s=service.t_s,
        duration_s=a.duration_s if a else None,
        segments=int((~a.starts_run[1:]).sum()) if a else 0,
    )


@router.put(
    "/api/replay3d",
    response_model=Replay3DState,
    summary="Show a session (and an overlay) in the 3D replay panel",
    dependencies=[Depends(require_control_token)],
)
async def put_replay3d(request: Request, body: Replay3DLoad) -> Replay3DState:
    service = await _service(request)
    settings = request.app.state.settings
    store = get_recorder(request).store  # the station's one SessionStore
    ref = reference_param(body.reference)
    viser = settings.viser

    def read():  # file reads and geodesy: off the event loop
        a = load_trajectory(store, body.session, body.align, ref, viser)
        b = load_trajectory(store, body.overlay, body.align, ref, viser) if body.overlay else None
        return a, b

    a, b = await asyncio.to_thread(read)
    await on_viser_loop(service.server, functools.partial(service.load, a, b))
    return _state(service)


@router.put(
    "/api/replay3d/time",
    response_model=Replay3DState,
    summary="Move the 3D replay panel's vehicle to an instant",
    dependencies=[Depends(require_control_token)],
)
async def put_replay3d_time(request: Request, body: Replay3DTime) -> Replay3DState:
    service = await _service(request)
    if not math.isfinite(body.t_s):
        raise BadRequest("t_s must be a finite number of seconds.")
    if service.primary is None:
        raise BadRequest("No session loaded: PUT /api/replay3d first.")
    await on_viser_loop(service.server, functools.partial(service.set_time, body.t_s))
    return _state(service)
