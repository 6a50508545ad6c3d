"""Flight analysis over REST: the paper's task metrics as JSON and its figures as PNG, for
one recorded session or a comparison of several.

    GET /api/sessions/{id}/analysis?task=hover[&reference=LAT,LON&flight=N&...thresholds]
    GET /api/sessions/{id}/analysis/{plot}.png?task=...     plot: trajectory3d|birdseye|history
    GET /api/analysis?task=...&sessions=ID&sessions=ID2     one table over several sessions
    GET /api/analysis/{plot}.png?task=...&sessions=...

Sessions are found only through the recorder's `SessionStore` (ids and file names are
untrusted). Loading and plotting run in the station's analysis worker process
(`server.analysis_worker`: a few jobs at a time, more get 503 `AnalysisBusy`), never in
the station's process, whose time belongs to the flight state. Answers are cached by the
files' size and modification time and the parsed parameters (query junk changes
nothing), and the worker keeps the last few analyses, so a page asking for the table and
three figures loads the session once. The JSON is the CLI's
`TABLE.json`, computed by the same `analysis.report.analyze_tracks`: one row per flight
(`flight=N` for the N-th only), and `skipped` the flights without a trial of the task.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal, overload

import anyio
from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import Response

from fpv_station.analysis import errors as ae
from fpv_station.analysis.errors import without_dirs
from fpv_station.analysis.plots import PLOTS
from fpv_station.analysis.tasks import TaskParams, check_task
from fpv_station.companion.recording import layout
from fpv_station.companion.recording import store as st
from fpv_station.server.analysis_worker import AnalysisJob, Stamp, run_job
from fpv_station.server.errors import ApiError, BadRequest, NotFound
from fpv_station.server.routes.recording import get_recorder
from fpv_station.server.routes.trajectory import reference_param

router = APIRouter(tags=["analysis"])
MAX_SESSIONS = 8


class Unprocessable(ApiError):
    """The session is readable but the analysis cannot be done (422)."""

    status_code = 422


class NoGpsFix(Unprocessable):
    pass


class TooFewPoints(Unprocessable):
    pass


class NoTaskWindow(Unprocessable):
    pass


class UnreadableSession(Unprocessable):
    pass


_ERRORS: dict[type[Exception], type[ApiError]] = {
    ae.UnknownTaskError: BadRequest,
    ae.NoGpsFixError: NoGpsFix,
    ae.TooFewPointsError: TooFewPoints,
    ae.TaskWindowError: NoTaskWindow,
    ae.TrackLoadError: UnreadableSession,
}


def _api_error(exc: Exception) -> ApiError:
    """The error for a client: its message names sessions and files, never folders."""
    msg = without_dirs(str(exc))
    for kind, api in _ERRORS.items():
        if isinstance(exc, kind):
            return api(msg)
    return Unprocessable(msg)


def _session_files(store: st.SessionStore, session_id: str) -> tuple[Path, Path | None]:
    """The telemetry file (CSV, else the tlog) and session.json, through the store."""
    store.resolve(session_id)
    try:
        data = store.file(session_id, layout.TELEMETRY_CSV)
    except st.SessionFileNotFound:
        try:
            data = store.file(session_id, layout.MAVLINK_TLOG)
        except st.SessionFileNotFound:
            raise st.SessionFileNotFound(
                f"Session '{session_id}' has neither {layout.TELEMETRY_CSV} nor "
                f"{layout.MAVLINK_TLOG} to analyse."
            ) from None
    try:
        meta = store.file(session_id, layout.SESSION_JSON)
    except st.SessionFileNotFound:
        meta = None
    return data, meta


def _stamp(path: Path) -> Stamp:
    s = path.stat()
    return (str(path), s.st_mtime_ns, s.st_size)


def _job(
    request: Request,
    session_ids: list[str],
    task: str,
    reference: tuple[float, float] | None,
    params: TaskParams,
    flight: int | None,
    plot: str | None,
) -> AnalysisJob:
    """Blocking (the store and stat): what decides the answer, files by their stamps."""
    store = get_recorder(request).store  # the station's one SessionStore
    files = []
    for sid in session_ids:
        data, meta = _session_files(store, sid)
        files.append((sid, _stamp(data), _stamp(meta) if meta is not None else None))
    scene = request.app.state.settings.twin.scene
    return AnalysisJob(
        tuple(files), task, reference, str(scene) if scene else None, params, flight, plot
    )


@overload
async def _run(
    request: Request,
    session_ids: list[str],
    task: str,
    reference: str | None,
    params: TaskParams,
    plot: None = None,
    flight: int | None = None,
) -> dict: ...  # the table


@overload
async def _run(
    request: Request,
    session_ids: list[str],
    task: str,
    reference: str | None,
    params: TaskParams,
    plot: str,
    flight: int | None = None,
) -> bytes: ...  # the figure's PNG


async def _run(
    request: Request,
    session_ids: list[str],
    task: str,
    reference: str | None,
    params: TaskParams,
    plot: str | None = None,
    flight: int | None = None,
) -> dict | bytes:
    if not session_ids:
        raise BadRequest("Give at least one session (sessions=ID).")
    if len(session_ids) > MAX_SESSIONS:
        raise BadRequest(f"At most {MAX_SESSIONS} sessions in one comparison.")
    if plot is not None and plot not in PLOTS:
        raise NotFound(f"No plot '{plot}'; use one of: {', '.join(PLOTS)}.")
    ref = reference_param(reference)
    try:
        check_task(task)
        job = await anyio.to_thread.run_sync(
            _job, request, session_ids, task, ref, params, flight, plot
        )
        # Off the station's process, bounded, cached (server/analysis_worker.py).
        return await request.app.state.station.analysis_worker.run(job, run_job, job)
    except ae.AnalysisError as exc:  # store errors: 400/404 by server.errors
        raise _api_error(exc) from None


_TASK = Query(..., description="hover, a-to-b, obstacle or figure8")
_REF = Query(None, description="LAT,LON of the point that sets +x")
_D = TaskParams()
_FLIGHT = Query(None, ge=1, description="only the N-th flight of each session (from 1)")


def _thresholds(
    hover_height_m: float = Query(_D.hover_height_m, gt=0),
    hover_window_s: float = Query(_D.hover_window_s, gt=0),
    hover_height_tolerance_m: float = Query(_D.hover_height_tolerance_m, ge=0),
    margin_m: float = Query(_D.margin_m, ge=0),
    airborne_height_m: float = Query(_D.airborne_height_m, ge=0),
    height_source: Literal["pilot", "gps"] = Query(_D.height_source),
) -> TaskParams:
    """The method's thresholds as query parameters, the paper's values by default."""
    return TaskParams(
        hover_height_m=hover_height_m,
        hover_window_s=hover_window_s,
        hover_height_tolerance_m=hover_height_tolerance_m,
        margin_m=margin_m,
        airborne_height_m=airborne_height_m,
        height_source=height_source,
    )


_P = Depends(_thresholds)


def _table(table: dict) -> dict:
    """The CLI's TABLE.json, with each row's source its session id (not its folder)."""
    results = [{**row, "source": Path(row["source"]).name} for row in table["results"]]
    skipped = [{**s, "reason": without_dirs(s["reason"])} for s in table["skipped"]]
    return {**table, "results": results, "skipped": skipped}


@router.get("/api/sessions/{session_id}/analysis", summary="Task metrics of one session")
async def session_analysis(
    request: Request,
    session_id: str,
    task: str = _TASK,
    reference: str | None = _REF,
    params: TaskParams = _P,
    flight: int | None = _FLIGHT,
) -> dict:
    table = await _run(request, [session_id], task, reference, params, flight=flight)
    return {"sessions": [session_id], **_table(table)}


@router.get("/api/sessions/{session_id}/analysis/{plot}.png", summary="A figure of one session")
async def session_plot(
    request: Request,
    session_id: str,
    plot: str,
    task: str = _TASK,
    reference: str | None = _REF,
    params: TaskParams = _P,
    flight: int | None = _FLIGHT,
) -> Response:
    png = await _run(request, [session_id], task, reference, params, plot, flight)
    return Response(png, media_type="image/png")


@router.get("/api/analysis", summary="One table comparing sessions of one task")
async def compare_sessions(
    request: Request,
    task: str = _TASK,
    sessions: list[str] | None = Query(None),
    reference: str | None = _REF,
    params: TaskParams = _P,
    flight: int | None = _FLIGHT,
) -> dict:
    table = await _run(request, sessions or [], task, reference, params, flight=flight)
    return {"sessions": sessions or [], **_table(table)}


@router.get("/api/analysis/{plot}.png", summary="A figure overlaying sessions of one task")
async def compare_plot(
    request: Request,
    plot: str,
    task: str = _TASK,
    sessions: list[str] | None = Query(None),
    reference: str | None = _REF,
    params: TaskParams = _P,
    flight: int | None = _FLIGHT,
) -> Response:
    png = await _run(request, sessions or [], task, reference, params, plot, flight)
    return Response(png, media_type="image/png")
