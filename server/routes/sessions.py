"""Recorded sessions: list, metadata, zip download, single files, delete.

Every id and path goes through `SessionStore`, which refuses anything that could leave
the sessions directory; its typed errors map onto the one error shape here.
"""

from __future__ import annotations

import asyncio
import dataclasses
from typing import Any

from fastapi import APIRouter, Depends
from fastapi.responses import FileResponse, Response, StreamingResponse
from pydantic import BaseModel

from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import (
    Demonstration,
    OnboardLog,
    SessionMeta,
    SessionTask,
    TrialScore,
)
from fpv_station.companion.recording.recorder import Recorder
from fpv_station.companion.recording.store import SessionSummary, is_frame_file
from fpv_station.server.auth import require_control_token
from fpv_station.server.errors import Conflict
from fpv_station.server.routes.recording import get_recorder
from fpv_station.server.trials import public_score
from fpv_station.server.zipstream import stream_zip

router = APIRouter(tags=["sessions"])

FRAME_MAX_AGE_S = 3600  # how long a browser may keep a frame served out of a pack


class QualityFlagModel(BaseModel):
    kind: str  # crash, failsafe, telemetry_gap, link_loss, dropped_frames, telemetry_rows
    reason: str  # in plain words, with the threshold it went over


class SessionSummaryModel(BaseModel):
    id: str
    start_wall: float | None
    start_utc: str | None
    end_wall: float | None
    duration_s: float | None
    source: str
    status: str  # recording, complete, interrupted, cut_short, unreadable
    recovered: bool = False  # interrupted, and its files counted and repaired afterwards
    stop_reason: str | None
    size_bytes: int
    telemetry_rows: int | None
    frames_written: dict[str, int]
    frames_dropped: dict[str, int]
    skew_p99_s: dict[str, float | None]  # camera -> p99 of row-to-frame skew
    recording_now: bool
    task: SessionTask | None = None  # the flight task chosen before the session
    demonstration: Demonstration | None = None  # who flew it as a demonstration
    score: TrialScore | None = None  # its score, once the vehicle disarmed
    onboard_log: OnboardLog | None = None  # the autopilot's own log, once fetched
    # Real problems (companion.recording.flags.QUALITY_THRESHOLDS), not every imperfection.
    flags: list[QualityFlagModel] = []


class SessionDetailModel(BaseModel):
    summary: SessionSummaryModel
    meta: SessionMeta | None
    files: list[str]  # every file but format 1's frame files (see each camera's frames.csv)
    frame_files: dict[str, int]  # camera -> frames on disk (in its frames.mjpeg, or files)


def _summary_model(s: SessionSummary, recording_id: str | None) -> SessionSummaryModel:
    data: dict[str, Any] = {
        k: getattr(s, k) for k in SessionSummaryModel.model_fields if hasattr(s, k)
    }
    if s.meta is not None:  # stamped in the clock the session chose (session.json "clock")
        data["start_utc"] = s.meta.start_utc
    else:
        data["start_utc"] = layout.utc_label(s.start_wall) if s.start_wall is not None else None
    data["recording_now"] = s.id == recording_id
    cams = s.meta.quality.cameras if s.meta is not None else {}
    data["skew_p99_s"] = {c: q.skew_p99_s for c, q in cams.items()}
    if s.meta is not None:
        data["task"], data["score"] = s.meta.task, public_score(s.meta.score)
        data["demonstration"] = s.meta.demonstration
        data["onboard_log"] = s.meta.onboard_log
        data["recovered"] = s.meta.recovery is not None
    data["flags"] = [dataclasses.asdict(f) for f in s.flags]
    return SessionSummaryModel.model_validate(data)


@router.get(
    "/api/sessions", response_model=list[SessionSummaryModel], summary="Sessions, newest first"
)
async def list_sessions(recorder: Recorder = Depends(get_recorder)) -> list[SessionSummaryModel]:
    summaries = await asyncio.to_thread(recorder.store.list)
    return [_summary_model(s, recorder.recording_id) for s in summaries]


@router.get(
    "/api/sessions/{session_id}",
    response_model=SessionDetailModel,
    summary="A session's metadata and quality report",
)
async def get_session(
    session_id: str, recorder: Recorder = Depends(get_recorder)
) -> SessionDetailModel:
    def load() -> SessionDetailModel:
        summary = recorder.store.summary(session_id)
        every = [rel for rel, _ in recorder.store.files(session_id)]
        return SessionDetailModel(
            summary=_summary_model(summary, recorder.recording_id),
            meta=(
                summary.meta.model_copy(update={"score": public_score(summary.meta.score)})
                if summary.meta is not None
                else None
            ),
            files=[rel for rel in every if not is_frame_file(rel)],
            frame_files=recorder.store.frame_counts(session_id, every),
        )

    return await asyncio.to_thread(load)


@router.get(
    "/api/sessions/{session_id}/download",
    summary="The whole session as a zip (streamed)",
    response_class=StreamingResponse,
)
async def download_session(
    session_id: str, recorder: Recorder = Depends(get_recorder)
) -> StreamingResponse:
    files = await asyncio.to_thread(recorder.store.files, session_id)
    entries = [(f"{session_id}/{rel}", path) for rel, path in files]
    return StreamingResponse(
        stream_zip(entries),
        media_type="application/zip",
        headers={"Content-Disposition": f'attachment; filename="{session_id}.zip"'},
    )


@router.get(
    "/api/sessions/{session_id}/files/{path:path}",
    summary="One file of a session, or one frame by its name (front/00000042.jpg)",
    response_class=FileResponse,
)
async def session_file(
    session_id: str, path: str, recorder: Recorder = Depends(get_recorder)
) -> Response:
    found = await asyncio.to_thread(recorder.store.file_or_frame, session_id, path)
    if isinstance(found, bytes):  # a frame out of its camera's frames.mjpeg (format 2)
        name = path.rsplit("/", 1)[-1]
        headers = {
            "Content-Disposition": f'inline; filename="{name}"',
            # A listed frame's bytes never change (the pack only grows; a recovery only
            # cuts what no row lists): a replay scrubbed back needs not fetch it again.
            "Cache-Control": f"private, max-age={FRAME_MAX_AGE_S}",
        }
        return Response(found, media_type="image/jpeg", headers=headers)
    return FileResponse(found, filename=found.name, content_disposition_type="inline")


@router.delete(
    "/api/sessions/{session_id}",
    dependencies=[Depends(require_control_token)],
    summary="Delete a session (refused while it is recorded)",
)
async def delete_session(
    session_id: str, recorder: Recorder = Depends(get_recorder)
) -> dict[str, str]:
    await asyncio.to_thread(recorder.store.resolve, session_id)
    if recorder.recording_id == session_id:
        raise Conflict(f"Session '{session_id}' is being recorded; stop it first.")
    await asyncio.to_thread(recorder.store.delete, session_id)
    return {"deleted": session_id}
