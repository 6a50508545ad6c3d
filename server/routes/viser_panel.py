"""The 3D panels, through the station's own door: viser's client page, each viewer's
WebSocket relayed to the panel's viser server on loopback (server/trajectory3d/gate.py),
and where the pages find them.

    GET /3d/live/, /3d/replay/       viser's client (it connects to the same path, ws://)
    WS  /3d/live, /3d/replay         a viewer; `?token=` lets it change what all viewers see
    GET /api/viser                   the panels' paths and the trail's size

viser's client is served from the station's own origin, beside the pilot page and its
token: told by its `?websocket=` where to connect, a crafted link could make it load a
scene, and viser's RunJavascriptMessage, from another server. So the page is refused
unless its `?websocket=` names this station's own panel, and it carries a
Content-Security-Policy whose `connect-src` allows this station only.

The WebSocket routes meet the guard (Origin, Host), the connection table and the frame
limit (`MAX_FRAME_BYTES`) as every route does, then the 3D viewer cap
(server/client_limits.py): beyond it a viewer is refused with 503 before its relay opens.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Literal
from urllib.parse import urlsplit

from fastapi import APIRouter, Request, WebSocket
from fastapi.responses import FileResponse
from pydantic import BaseModel

from fpv_station.server.auth import require_control_token
from fpv_station.server.errors import (
    BadRequest,
    NotFound,
    Unauthorized,
    Unavailable,
    deny_websocket,
)
from fpv_station.server.station import Station, start_3d_panels
from fpv_station.server.trajectory3d.gate import ViewerRules, relay

router = APIRouter(tags=["trajectory"])

Panel = Literal["live", "replay"]
LIVE_PATH, REPLAY_PATH = "/3d/live/", "/3d/replay/"
VIEWER_PATHS = (LIVE_PATH.rstrip("/"), REPLAY_PATH.rstrip("/"))  # the WebSockets
# A viewer's frames: its camera (~250 bytes) and GUI changes; a larger one is refused as it
# starts (1009, server/listen.py), before its payload is read.
MAX_FRAME_BYTES = 4096


class ViserPanel(BaseModel):
    enabled: bool
    path: str | None  # the live panel's page on this server (None with --no-3d)
    replay_path: str | None = None  # the replay page's panel (PUT /api/replay3d)
    # The viser servers' own ports, on loopback: reached through the paths above only.
    port: int | None
    replay_port: int | None = None
    points: int  # trail points drawn so far
    chunks: int  # trail chunks (scene handles) drawn so far (none until someone watches)


@router.get("/api/viser", response_model=ViserPanel, summary="The 3D trajectory panels")
async def get_viser_panel(request: Request) -> ViserPanel:
    station = request.app.state.station
    await start_3d_panels(station)  # the first visit starts the panels' viser servers
    service = station.trajectory3d
    if service is None or service.server is None:
        return ViserPanel(enabled=False, path=None, port=None, points=0, chunks=0)
    replay = station.replay3d
    replay_up = replay is not None and replay.server is not None
    return ViserPanel(
        enabled=True,
        path=LIVE_PATH,
        replay_path=REPLAY_PATH if replay_up else None,
        port=service.port,
        replay_port=replay.port if replay_up else None,
        points=service.trail.n_points,
        chunks=len(service.scene.chunk_handles) if service.scene else 0,
    )


def _client_page() -> Path:
    """viser's built client (one HTML file), found without importing viser."""
    spec = importlib.util.find_spec("viser")
    if spec is None or spec.origin is None:
        raise NotFound("The 3D panel's client (viser) is not installed.")
    return Path(spec.origin).parent / "client" / "build" / "index.html"


@router.get(LIVE_PATH, include_in_schema=False)
@router.get(REPLAY_PATH, include_in_schema=False)
async def viser_client_page(request: Request) -> FileResponse:
    if request.app.state.station.trajectory3d is None:
        raise NotFound("The 3D panels are off (--no-3d).")
    host = request.headers.get("host", "")
    own = request.url.path.rstrip("/")
    for url in request.query_params.getlist("websocket"):
        parts = urlsplit(url)
        if parts.scheme not in ("ws", "wss") or parts.netloc != host or parts.path != own:
            raise BadRequest(f"The 3D panel connects to this station's {own} only.")
    policy = f"connect-src 'self' ws://{host} wss://{host} data: blob:; frame-ancestors 'self'"
    return FileResponse(
        _client_page(),
        media_type="text/html; charset=utf-8",
        headers={"Content-Security-Policy": policy},
    )


@router.websocket(VIEWER_PATHS[0])
async def live_viewer(ws: WebSocket) -> None:
    await _serve_viewer(ws, "live")


@router.websocket(VIEWER_PATHS[1])
async def replay_viewer(ws: WebSocket) -> None:
    await _serve_viewer(ws, "replay")


async def _serve_viewer(ws: WebSocket, which: Panel) -> None:
    station: Station = ws.app.state.station
    try:
        with station.client_limits.viewers3d.slot():
            await start_3d_panels(station)
            panel = station.trajectory3d if which == "live" else station.replay3d
            if panel is None or panel.server is None:
                await deny_websocket(ws, 404, "NotFound", "The 3D panels are off (--no-3d).")
                return
            rules = ViewerRules(panel.viewer_inputs(), authorized=_has_token(ws))
            await relay(ws, panel.port, rules, panel.upstream_path(rules.authorized))
    except Unavailable as exc:
        await deny_websocket(ws, 503, "Unavailable", exc.message)
    except OSError as exc:  # raised before the viewer was accepted
        await deny_websocket(ws, 503, "Unavailable", str(exc))


def _has_token(ws: WebSocket) -> bool:
    """Whether the viewer may change what every viewer sees: it presented the control
    token (`?token=`), or the station has none. A wrong or missing token still watches."""
    try:
        require_control_token(ws)
    except Unauthorized:
        return False
    return True
