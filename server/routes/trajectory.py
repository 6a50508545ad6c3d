"""A recorded session's trajectory for the replay view: ENU arrays with times and frames.

Sessions are resolved only through the recorder's `SessionStore` (which refuses
traversal and bad ids) and loaded through `analysis.track`, so the replay draws exactly
what the analysis measures. Its one time axis is the session clock, on which the recorder
stamps rows and frames: each fix is drawn at the first row that holds it (`row_t_s`), not
at the vehicle's time of it, so the path, the rows and the frames of an instant agree.
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
from fastapi import APIRouter, Query, Request

from fpv_station.analysis.errors import NoGpsFixError, TrackLoadError
from fpv_station.analysis.track import load_session_dir
from fpv_station.companion.recording import frame_pack, layout
from fpv_station.companion.recording.store import (
    InvalidPath,
    SessionStore,
)
from fpv_station.core.geodesy import LatLonError, parse_latlon
from fpv_station.server.errors import BadRequest
from fpv_station.server.routes.recording import get_recorder
from fpv_station.server.settings import ViserSettings
from fpv_station.server.trajectory3d.replay import (
    Align,
    CameraFrames,
    TrajectoryReply,
    build_trajectory,
)

router = APIRouter(tags=["trajectory"])


def reference_param(text: str | None) -> tuple[float, float] | None:
    """A `reference=LAT,LON` query value (None when absent); bad text is a 400."""
    if not text:
        return None
    try:
        return parse_latlon(text)
    except LatLonError as exc:
        raise BadRequest(f"reference: {exc}") from None


def load_trajectory(
    store: SessionStore,
    session_id: str,
    align: Align,
    reference: tuple[float, float] | None,
    viser: ViserSettings,
) -> TrajectoryReply:
    """Blocking: reads the session's files (run it in a thread)."""
    folder: Path = store.resolve(session_id)  # store errors answer 400/404 (server.errors)
    try:
        track = load_session_dir(folder)
    except (TrackLoadError, NoGpsFixError) as exc:
        raise BadRequest(f"Session '{session_id}' has no trajectory to draw: {exc}") from None
    cameras: list[CameraFrames] = []
    for camera in layout.CAMERAS:
        # The index the file route serves frames by (the store's, kept between requests);
        # only frames whose bytes are on disk.
        try:
            index = store.frame_index(session_id, camera)
        except InvalidPath:
            continue
        if index is None:
            continue  # a session without this camera
        index = index.where(frame_pack.on_disk(folder, index) & np.isfinite(index.t_s))
        order = np.argsort(index.t_s, kind="stable")  # capture order, as written
        names = [index.name(int(k)) for k in order]
        cameras.append(CameraFrames(camera, index.t_s[order], names))
    try:
        return build_trajectory(
            session_id,
            track.row_t_s,
            track.lat_deg,
            track.lon_deg,
            track.alt_m,
            armed=track.armed,
            relative_alt_m=track.relative_alt_m,
            speed_mps=track.ground_speed_mps,
            cameras=cameras,
            gap_s=viser.gap_s,
            align=align,
            reference_latlon=reference,
            height_range_m=viser.height_range_m,
            session_end_s=_number(track.meta.get("duration_s")),
        )
    except ValueError as exc:
        raise BadRequest(f"Session '{session_id}': {exc}") from None


def _number(value: object) -> float | None:
    """A number from session.json, None when it holds something else."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    return None


@router.get(
    "/api/sessions/{session_id}/trajectory",
    response_model=TrajectoryReply,
    summary="A session's path in ENU metres with times and the frame of each instant",
)
async def get_trajectory(
    request: Request,
    session_id: str,
    align: Align = Query(
        "none",
        description="rotate so that start-to-'end' (last point) or start-to-'farthest' "
        "point lies along +x, as in the paper; 'none' keeps east-north-up",
    ),
    reference: str | None = Query(None, description="LAT,LON put on +x (the paper's alignment)"),
) -> TrajectoryReply:
    settings = request.app.state.settings
    store = get_recorder(request).store  # the station's one SessionStore
    ref = reference_param(reference)
    return await asyncio.to_thread(load_trajectory, store, session_id, align, ref, settings.viser)
