"""A recorded flight as the replay view draws it: ENU arrays with times, gaps, and the
front and bottom frame of each instant.

Pure numpy over the columns of an `analysis.track.Track` and the cameras' frames (as the
recorder's `frame_pack.read_index` lists them); the route does the file access. Origin: the arming point (the first armed sample), else
the first fix. Optional alignment as in the paper: rotated about the vertical so that the
line from the origin to a reference point lies along +x: a given point (the landing pad),
the last point ("end", for A-to-B flights), or the point farthest from the origin
("farthest": also right for flights that come back, such as the figure 8).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel

from fpv_station.analysis.flight_frame import arming_origin_index, rotation_to
from fpv_station.core.geodesy import geodetic_to_enu, rotate_about_up
from fpv_station.server.settings import ViserSettings
from fpv_station.server.trajectory3d.colors import ramp_hex

Align = Literal["none", "end", "farthest"]
_HEIGHT_RANGE_M: tuple[float, float] = ViserSettings.model_fields["height_range_m"].default


class GeoPoint(BaseModel):
    lat_deg: float
    lon_deg: float
    alt_m: float | None = None


class FrameTimeline(BaseModel):
    """One camera's frames in capture order: capture time (session clock) and name."""

    t_s: list[float]
    file: list[str]


class TrajectoryReply(BaseModel):
    """ENU metres about `origin` (x east, y north, z up), or the paper's aligned frame.

    Every time is on the session clock (telemetry.csv's and frames.csv's `t_s`): a fix is
    at the first row that holds it, so at any instant the path shows what the row shows,
    and the frame of an instant is the newest one captured at or before it."""

    id: str
    origin: GeoPoint
    reference: GeoPoint | None  # the point put on +x when aligned
    align_rad: float  # rotation applied about the vertical (0 when not aligned)
    t_s: list[float]  # session clock of each fix
    duration_s: float  # session clock of the last row, fix or frame: the replay's span
    x_m: list[float]
    y_m: list[float]
    z_m: list[float]
    speed_mps: list[float | None]
    starts_run: list[bool]  # True where a gap (no fix, or silence > gap_s) ends
    color: list[str]  # "#rrggbb" per point: height on the 3D panels' ramp (pages draw it)
    frames: dict[str, list[str | None]]  # camera -> file (relative to the session) per fix
    frame_index: dict[str, FrameTimeline]  # camera -> every frame, for instants between fixes


@dataclass(frozen=True, slots=True)
class CameraFrames:
    """One camera's frames in capture order: capture time (session clock) and name."""

    camera: str
    t_s: NDArray[np.float64]
    relpath: list[str]


def frames_at(times_s: NDArray[np.float64], frames: CameraFrames) -> list[str | None]:
    """The newest frame captured at or before each time (None before the first frame)."""
    if frames.t_s.size == 0:
        return [None] * len(times_s)
    idx = np.searchsorted(frames.t_s, np.asarray(times_s, float), side="right") - 1
    return [frames.relpath[i] if i >= 0 else None for i in idx]


def build_trajectory(
    session_id: str,
    t_s: NDArray[np.float64],
    lat_deg: NDArray[np.float64],
    lon_deg: NDArray[np.float64],
    alt_m: NDArray[np.float64],
    armed: NDArray[np.bool_] | None = None,
    relative_alt_m: NDArray[np.float64] | None = None,
    speed_mps: NDArray[np.float64] | None = None,
    cameras: list[CameraFrames] | None = None,
    gap_s: float = 1.0,
    align: Align = "none",
    reference_latlon: tuple[float, float] | None = None,
    height_range_m: tuple[float, float] = _HEIGHT_RANGE_M,
    session_end_s: float | None = None,
) -> TrajectoryReply:
    """The reply for one session's fixes (rows without a fix already dropped), in the
    analysis' flight frame (`analysis.flight_frame`: same origin, same turn).
    `session_end_s`: the session clock of its last row, when known."""
    t = np.asarray(t_s, float)
    lat, lon, alt = (np.asarray(a, float) for a in (lat_deg, lon_deg, alt_m))
    if t.size == 0:
        raise ValueError("The session has no GPS fix to draw.")
    i0 = arming_origin_index(armed, relative_alt_m) if armed is not None else 0
    origin = (float(lat[i0]), float(lon[i0]), float(alt[i0]))
    enu = geodetic_to_enu(lat, lon, alt, *origin)
    reference: GeoPoint | None = None
    angle = 0.0
    if reference_latlon is not None or align != "none":
        if reference_latlon is not None:
            ref_lat, ref_lon = reference_latlon
        else:
            k = -1 if align == "end" else int(np.argmax(np.hypot(enu[:, 0], enu[:, 1])))
            ref_lat, ref_lon = float(lat[k]), float(lon[k])
        reference = GeoPoint(lat_deg=ref_lat, lon_deg=ref_lon)
        angle = rotation_to(geodetic_to_enu(ref_lat, ref_lon, origin[2], *origin))
        enu = rotate_about_up(enu, angle)
    starts = np.ones(t.size, bool)
    starts[1:] = (np.diff(t) > gap_s) | (np.diff(t) < 0)
    speed = np.full(t.size, np.nan) if speed_mps is None else np.asarray(speed_mps, float)
    cameras = cameras or []
    ends = [float(c.t_s[-1]) for c in cameras if c.t_s.size] + [float(t.max())]
    if session_end_s is not None and math.isfinite(session_end_s):
        ends.append(float(session_end_s))
    return TrajectoryReply(
        id=session_id,
        origin=GeoPoint(lat_deg=origin[0], lon_deg=origin[1], alt_m=origin[2]),
        reference=reference,
        align_rad=angle,
        t_s=_rounded(t, 6),
        duration_s=round(max(ends), 6),
        x_m=_rounded(enu[:, 0], 3),
        y_m=_rounded(enu[:, 1], 3),
        z_m=_rounded(enu[:, 2], 3),
        speed_mps=[None if not math.isfinite(v) else round(v, 3) for v in speed.tolist()],
        starts_run=starts.tolist(),
        color=ramp_hex(enu[:, 2], *height_range_m),
        frames={c.camera: frames_at(t, c) for c in cameras},
        frame_index={c.camera: FrameTimeline(t_s=c.t_s.tolist(), file=c.relpath) for c in cameras},
    )


def _rounded(a: NDArray[np.float64], digits: int) -> list[float]:
    """Millimetres are plenty for GPS tracks and keep the JSON small."""
    return np.round(a, digits).tolist()
