"""Sessions selected for learning and their exports (server.exports).

    GET  /api/selection?select=TERMS[&include_failed=true]
                        the sessions `fpv-station export --select TERMS` takes (ids, oldest
                        first) and those left out only by a failed trial, with why
    POST /api/exports   {"select": TERMS, "include_failed": false, "format": "lerobot"}
                        (control): export them in a process of its own; 202 with its record
    GET  /api/exports   every export, newest first (its record: state, sessions, figures)
    GET  /api/exports/{id}            one export's record
    GET  /api/exports/{id}/download   a finished export as a zip (streamed)

TERMS: `task=1,pilot=Ana,kind=human,hover_distance_m<=0.3` (analysis.selection).
"""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, Depends, Request
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, ConfigDict, Field, field_validator

from fpv_station.analysis.selection import METRICS, Selection, SelectionError, select_sessions
from fpv_station.companion.recording.recorder import Recorder
from fpv_station.learn.formats import FORMATS
from fpv_station.server.auth import require_control_token
from fpv_station.server.errors import BadRequest, NotFound
from fpv_station.server.exports import ExportRecord, Exports
from fpv_station.server.routes.recording import get_recorder
from fpv_station.server.zipstream import stream_zip

router = APIRouter(tags=["exports"])

MAX_SELECT = 1000  # characters of a selection's text


class SelectionReply(BaseModel):
    select: str  # the selection as understood, written out
    include_failed: bool
    sessions: list[str]  # selected, oldest first
    failed: dict[str, str]  # kept out only by a failed trial: id -> why
    metrics: list[str] = list(METRICS)  # the score's figures a term may bound (METRIC<=X)


class ExportRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    select: str = Field("", max_length=MAX_SELECT)
    include_failed: bool = False
    format: str = "lerobot"

    @field_validator("format")
    @classmethod
    def _format(cls, v: str) -> str:
        if v not in FORMATS:
            raise ValueError(f"one of {', '.join(FORMATS)}")
        return v


def _selection(text: str, include_failed: bool) -> Selection:
    try:
        return Selection.parse(text, include_failed)
    except SelectionError as exc:
        raise BadRequest(f"Selection '{text[:80]}': {exc}") from None


def _exports(request: Request) -> Exports:
    exports = request.app.state.station.exports
    if exports is None:
        raise NotFound("This station does not record, so it has no exports.")
    return exports


@router.get("/api/selection", response_model=SelectionReply, summary="Sessions selected")
async def get_selection(
    select: str = "", include_failed: bool = False, recorder: Recorder = Depends(get_recorder)
) -> SelectionReply:
    if len(select) > MAX_SELECT:
        raise BadRequest(f"A selection is at most {MAX_SELECT} characters.")
    selection = _selection(select, include_failed)
    chosen = await asyncio.to_thread(select_sessions, recorder.store, selection)
    return SelectionReply(
        select=selection.text(),
        include_failed=include_failed,
        sessions=chosen.sessions,
        failed=chosen.failed,
    )


@router.post(
    "/api/exports",
    response_model=ExportRecord,
    status_code=202,
    summary="Export the selected sessions (in a process of its own)",
    dependencies=[Depends(require_control_token)],
)
async def start_export(body: ExportRequest, request: Request) -> ExportRecord:
    selection = _selection(body.select, body.include_failed)
    return await _exports(request).start(selection, body.format)


@router.get("/api/exports", response_model=list[ExportRecord], summary="Exports, newest first")
async def list_exports(request: Request) -> list[ExportRecord]:
    return await asyncio.to_thread(_exports(request).list)


@router.get("/api/exports/{export_id}", response_model=ExportRecord, summary="One export")
async def get_export(export_id: str, request: Request) -> ExportRecord:
    record = await asyncio.to_thread(_exports(request).get, export_id)
    if record is None:
        raise NotFound(f"No export '{export_id[:40]}'.")
    return record


@router.get(
    "/api/exports/{export_id}/download",
    summary="A finished export as a zip (streamed)",
    response_class=StreamingResponse,
)
async def download_export(export_id: str, request: Request) -> StreamingResponse:
    files = await asyncio.to_thread(_exports(request).files, export_id)
    return StreamingResponse(
        stream_zip(files),
        media_type="application/zip",
        headers={"Content-Disposition": f'attachment; filename="{export_id}.zip"'},
    )
