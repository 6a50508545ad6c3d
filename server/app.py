"""The FastAPI app: routers, pages and the lifespan that runs the station."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

from fpv_station.server import __version__
from fpv_station.server.errors import install_error_handlers
from fpv_station.server.guard import RequestGuard, redact_tokens_in_logs
from fpv_station.server.routes import (
    analysis,
    control,
    demo,
    exports,
    health,
    onboard_log,
    recording,
    replay3d,
    sessions,
    status,
    task,
    telemetry,
    trajectory,
    video,
    video_ws,
    viser_panel,
)
from fpv_station.server.sd_notify import Notifier, notify_loop, notify_stopping
from fpv_station.server.settings import Settings
from fpv_station.server.station import open_station
from fpv_station.web import WEB_DIR


def create_app(settings: Settings) -> FastAPI:
    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        async with open_station(settings) as station:
            app.state.station = station
            # Under systemd: READY now, then the watchdog while tasks live (server/sd_notify.py).
            notifier = Notifier.from_environ()
            if notifier is not None:
                station.tasks.spawn("systemd-notify", notify_loop(notifier, station.tasks))
            yield
            notify_stopping(notifier)

    app = FastAPI(
        title="fpv-station",
        version=__version__,
        summary="Ground station for FPV flight demonstrations",
        lifespan=lifespan,
    )
    app.state.settings = settings
    # Each WebSocket route's largest frame, for the server (server/listen.py).
    app.state.ws_frame_limits = {
        "/ws/telemetry": telemetry.MAX_FRAME_BYTES,
        "/ws/control": control.MAX_FRAME_BYTES,
        "/ws/video": video_ws.MAX_FRAME_BYTES,
        **dict.fromkeys(viser_panel.VIEWER_PATHS, viser_panel.MAX_FRAME_BYTES),
    }
    install_error_handlers(app)
    # Host, Origin, content type and body size, before any route (server/guard.py).
    app.add_middleware(
        RequestGuard,
        allowed_origins=settings.server.allowed_origins,
        max_body_bytes=settings.server.max_body_bytes,
        allowed_hosts=[settings.server.host, *settings.server.allowed_hosts],
    )
    redact_tokens_in_logs()
    app.include_router(health.router)
    app.include_router(status.router)
    app.include_router(telemetry.router)
    app.include_router(recording.router)
    app.include_router(sessions.router)
    app.include_router(analysis.router)
    app.include_router(video.router)
    app.include_router(video_ws.router)
    app.include_router(viser_panel.router)
    app.include_router(trajectory.router)
    app.include_router(replay3d.router)
    app.include_router(control.router)
    app.include_router(task.router)
    app.include_router(demo.router)
    app.include_router(exports.router)
    app.include_router(onboard_log.router)
    app.mount("/", StaticFiles(directory=WEB_DIR, html=True), name="web")
    return app
