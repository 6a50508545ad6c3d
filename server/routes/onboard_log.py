"""The autopilot's own flight log of a session (server.onboard_logs).

GET  /api/onboard_log                     the current or last download, its progress
POST /api/sessions/{id}/onboard_log       fetch that session's log now (control);
                                          {"log_id": N} for one log, else the
                                          flight's (the newest that started before
                                          the session ended)
"""

from __future__ import annotations

import asyncio
import dataclasses

from fastapi import APIRouter, Body, Depends, Request
from pydantic import BaseModel, ConfigDict, Field

from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import read_meta
from fpv_station.server.auth import require_control_token
from fpv_station.server.errors import Conflict, Unavailable
from fpv_station.server.onboard_logs import OnboardLogs
from fpv_station.server.routes.recording import get_recorder

router = APIRouter(tags=["onboard log"])


class OnboardLogRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    log_id: int | None = Field(None, ge=1, le=0xFFFF)


class OnboardLogStatusModel(BaseModel):
    available: bool  # a live vehicle link to ask (not none, not a replay)
    after_disarm: bool  # fetched after every disarm (onboard_log.after_disarm)
    state: str  # idle, listing, downloading, complete, incomplete, no_log, failed, cancelled
    session: str | None = None
    log_id: int | None = None
    size_bytes: int = 0
    received_bytes: int = 0
    file: str | None = None
    message: str = ""
    download_s: float = 0.0
    re_requests: int = 0  # windows asked for again (lost on the way)
    lost_packets: int = 0  # the vehicle's packets the link lost during the download


def get_onboard_logs(request: Request) -> OnboardLogs:
    logs = request.app.state.station.onboard_logs
    if logs is None:
        raise Unavailable("The station is starting or stopping.")
    return logs


def _model(logs: OnboardLogs) -> OnboardLogStatusModel:
    status = dataclasses.asdict(logs.status())
    status.pop("dropped_packets", None)
    status.pop("logs_listed", None)
    return OnboardLogStatusModel(
        available=logs.available, after_disarm=logs.settings.after_disarm, **status
    )


@router.get("/api/onboard_log", summary="The autopilot's log download: state and progress")
async def onboard_log_status(
    logs: OnboardLogs = Depends(get_onboard_logs),
) -> OnboardLogStatusModel:
    return _model(logs)


@router.post(
    "/api/sessions/{session_id}/onboard_log",
    dependencies=[Depends(require_control_token)],
    summary="Fetch the autopilot's log of a session into it",
)
async def fetch_onboard_log(
    session_id: str,
    body: OnboardLogRequest | None = Body(None),
    logs: OnboardLogs = Depends(get_onboard_logs),
    recorder=Depends(get_recorder),
) -> OnboardLogStatusModel:
    folder = await asyncio.to_thread(recorder.store.resolve, session_id)
    if recorder.recording_id == session_id:
        raise Conflict(f"Session '{session_id}' is being recorded; fetch its log after it ends.")
    end_utc = None
    try:
        meta = await asyncio.to_thread(read_meta, folder / layout.SESSION_JSON)
    except (OSError, ValueError):  # a session cut off before its metadata: the newest log
        meta = None
    if meta is not None and meta.end_wall is not None:
        end_utc = meta.end_wall + (meta.clock.offset_s if meta.clock is not None else 0.0)
    logs.request(session_id, folder, body.log_id if body else None, end_utc)
    return _model(logs)
