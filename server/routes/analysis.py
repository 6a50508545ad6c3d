"""Flight analysis over REST: the paper's task metrics as JSON and its figures as PNG, for
one recorded session or a comparison of several.

    GET /api/sessions/{id}/analysis?task=hover[&reference=LAT,LON&flight=N&...thresholds]
    GET /api/sessions/{id}/analysis/{plot}.png?task=...     plot: trajectory3d|birdseye|history
    GET /api/analysis?task=...&sessions=ID&sessions=ID2     one table over several sessions
    GET /api/analysis/{plot}.png?task=...&sessions=...

Sessions are found only through the recorder's `SessionStore` (ids and file names are
untrusted). Loading and plotting run in a worker thread (one analysis at a time, so the
Pi's cores stay free for telemetry and video), never on the event loop; the
last few analyses are cached, keyed on the files' size and modification time, so a page
asking for the table and three figures loads the session once. The JSON is the CLI's
`TABLE.json`, computed by the same `analysis.report.analyze_tracks`: one row per flight
(`flight=N` for the N-th only), and `skipped` the flights without a trial of the task.
"""

from __future__ import annotations

import functools
from dataclasses import replace
from pathlib import Path
from typing import Literal

import anyio
from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import Response

from analysis import errors as ae
from analysis.errors import without_dirs
from analysis.field_layout import load_field_layout
from analysis.plots import PLOTS
from analysis.report import Analysis, analyze_tracks
from analysis.tasks import TaskParams
from analysis.track import load_track, parse_meta
from companion.recording import layout
from companion.recording import store as st
from server.errors import ApiError, BadRequest, NotFound
from server.routes.recording import get_recorder
from server.routes.trajectory import reference_param

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


def _stamp(path: Path | None) -> tuple[str, int, int] | None:
    if path is None:
        return None
    s = path.stat()
    return (str(path), s.st_mtime_ns, s.st_size)


@functools.lru_cache(maxsize=4)
def _cached(
    files: tuple[tuple[str, tuple, tuple | None], ...],
    task: str,
    reference: tuple[float, float] | None,
    scene: str | None,
    params: TaskParams,
    flight: int | None = None,
) -> Analysis:
    tracks = []
    for session_id, (data, _, _), meta in files:
        track = load_track(Path(data), label=session_id)
        m = parse_meta(Path(meta[0]).read_bytes()) if meta else {}
        tracks.append(replace(track, meta=m, source=str(Path(data).parent)))
    field = load_field_layout(scene)
    return analyze_tracks(tracks, task, reference, field, params, flight)


def _analyze(
    request: Request,
    session_ids: list[str],
    task: str,
    reference: str | None,
    params: TaskParams,
    flight: int | None,
) -> Analysis:
    """Runs in a worker thread: file access, parsing and numpy."""
    settings = request.app.state.settings
    store = get_recorder(request).store  # the station's one SessionStore
    files = []
    for sid in session_ids:
        data, meta = _session_files(store, sid)
        files.append((sid, _stamp(data), _stamp(meta)))
    scene = settings.twin.scene
    return _cached(
        tuple(files),
        task,
        reference_param(reference),
        str(scene) if scene else None,
        params,
        flight,
    )


async def _run(
    request: Request,
    session_ids: list[str],
    task: str,
    reference: str | None,
    params: TaskParams,
    plot: str | None = None,
    flight: int | None = None,
) -> Analysis | bytes:
    if not session_ids:
        raise BadRequest("Give at least one session (sessions=ID).")
    if len(session_ids) > MAX_SESSIONS:
        raise BadRequest(f"At most {MAX_SESSIONS} sessions in one comparison.")
    if plot is not None and plot not in PLOTS:
        raise NotFound(f"No plot '{plot}'; use one of: {', '.join(PLOTS)}.")

    def work() -> Analysis | bytes:
        try:
            an = _analyze(request, session_ids, task, reference, params, flight)
            return an if plot is None else an.plot(plot)
        except ae.AnalysisError as exc:  # store errors: 400/404 by server.errors
            raise _api_error(exc) from None

    limiter = request.app.state.station.analysis_limiter  # one analysis at a time
    return await anyio.to_thread.run_sync(work, limiter=limiter)


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


def _table(an: Analysis) -> dict:
    """The CLI's TABLE.json, with each row's source its session id (not its folder)."""
    skipped = [{"label": label, "reason": without_dirs(why)} for label, why in an.skipped]
    table = an.comparison.to_dict()
    for row in table["results"]:
        row["source"] = Path(row["source"]).name
    return {**table, "skipped": skipped}


@router.get("/api/sessions/{session_id}/analysis", summary="Task metrics of one session")
async def session_analysis(
    request: Request,
    session_id: str,
    task: str = _TASK,
    reference: str | None = _REF,
    params: TaskParams = _P,
    flight: int | None = _FLIGHT,
) -> dict:
    an = await _run(request, [session_id], task, reference, params, flight=flight)
    return {"sessions": [session_id], **_table(an)}


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
    an = await _run(request, sessions or [], task, reference, params, flight=flight)
    return {"sessions": sessions or [], **_table(an)}


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
