"""Where the browser finds the 3D panel: the viser server's port (it serves its own client)."""

from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel

from server.station import start_3d_panels

router = APIRouter(tags=["trajectory"])


class ViserPanel(BaseModel):
    enabled: bool
    port: int | None  # the port actually bound (viser moves on when the asked one is taken)
    points: int  # trail points drawn so far
    chunks: int  # trail chunks (scene handles) drawn so far (none until someone watches)
    replay_port: int | None = None  # the replay page's own viser server (PUT /api/replay3d)


@router.get("/api/viser", response_model=ViserPanel, summary="The 3D trajectory panel")
async def get_viser_panel(request: Request) -> ViserPanel:
    station = request.app.state.station
    await start_3d_panels(station)  # the first visit starts the panels' viser servers
    service = station.trajectory3d
    if service is None or service.server is None:
        return ViserPanel(enabled=False, port=None, points=0, chunks=0)
    replay = request.app.state.station.replay3d
    return ViserPanel(
        replay_port=replay.port if replay is not None and replay.server is not None else None,
        enabled=True,
        port=service.port,
        points=service.trail.n_points,
        chunks=len(service.scene.chunk_handles) if service.scene else 0,
    )
