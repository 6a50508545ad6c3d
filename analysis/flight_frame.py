"""The flight frame: ENU about the arming point, rotated so that the line from the start
to a reference point is +x (the paper's frame). x = longitudinal, y = lateral, z = height
above the start. The analysis (`align_track`) and the replay view
(`server.trajectory3d.replay`) both place the origin with `arming_origin_index` and turn
with `rotation_to`, so the replay draws the frame the analysis measures in.

The origin is the vehicle on the ground where it was armed: the last sample before the
vehicle reports armed, stepped back to the last sample at ground level if the pilot's
altitude already shows a climb there (or the first sample of a track never armed).

The reference, in order of preference: the one given (`--reference LAT,LON`); the scene's
landing pad (when the flight is on a known field); the landing point; the point farthest
from the start (a figure 8 lands where it took off, so its landing point gives no
direction). With none farther than `min_reference_m`, the ENU axes stay unrotated.

Heights: z is GPS height above the origin (the paper's, used for the height deviation
and the plots). GPS altitude wanders by metres over a flight, so deciding *when* things
happen (take-off, landing, reaching 4 m, touching an obstacle) uses the altitude the
pilot saw (`relative_alt_m`: barometric, since arming) wherever it was recorded.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fpv_station.analysis.errors import TooFewPointsError
from fpv_station.analysis.field_layout import FieldLayout
from fpv_station.analysis.track import Track
from fpv_station.core.geodesy import geodetic_to_enu, heading_alignment_rad, rotate_about_up

Array = NDArray[np.float64]
ReferenceKind = Literal["given", "scene", "landing", "farthest", "none"]
OriginKind = Literal["arming", "first"]
HeightSource = Literal["pilot", "gps"]


@dataclass(frozen=True)
class AlignedTrack:
    track: Track
    xyz_m: Array  # (n, 3) aligned frame
    origin: tuple[float, float, float]  # lat_deg, lon_deg, alt_m
    rotation_rad: float  # applied about Up to ENU
    reference_latlon: tuple[float, float] | None
    reference_kind: ReferenceKind
    field: FieldLayout | None  # the field's pads and obstacles in this frame, when known
    pilot_height_m: Array  # the altitude the pilot saw (since arming) where recorded, else z

    def height_m(self, source: HeightSource) -> Array:
        return self.pilot_height_m if source == "pilot" else self.xyz_m[:, 2]

    @property
    def t_s(self) -> Array:
        return self.track.t_s

    @property
    def label(self) -> str:
        return self.track.label


def arming_origin_index(
    armed: NDArray[np.bool_], relative_alt_m: Array | None = None, ground_height_m: float = 0.5
) -> int:
    """Index of the flight frame's origin sample (see the module's docstring)."""
    armed = np.asarray(armed, bool)
    if not armed.any():
        return 0
    # The last sample before the arming is seen: a disarmed vehicle is on the ground,
    # while the first armed sample can already be in the air (HEARTBEAT comes at 1 Hz
    # and a pilot climbs right after arming).
    i0 = max(int(np.argmax(armed)) - 1, 0)
    if relative_alt_m is None:
        return i0
    # Still late when the pilot's altitude already shows a climb: step back to the
    # last sample at ground level.
    rel = np.asarray(relative_alt_m, float)[: i0 + 1]
    grounded = np.flatnonzero(np.isfinite(rel) & (rel <= ground_height_m))
    if np.isfinite(rel[-1]) and rel[-1] > ground_height_m and grounded.size:
        i0 = int(grounded[-1])
    return i0


def rotation_to(reference_en: ArrayLike | None) -> float:
    """The turn about Up (rad) that puts the East-North point `reference_en` (about the
    origin) on +x; 0 with no reference or one at the origin (a pure hover)."""
    if reference_en is None or np.hypot(*np.asarray(reference_en, float)[:2]) <= 1e-6:
        return 0.0
    return heading_alignment_rad((0.0, 0.0), np.asarray(reference_en, float)[:2])


def align_track(
    track: Track,
    reference_latlon: tuple[float, float] | None = None,
    field: FieldLayout | None = None,
    reference_pad: str = "landing",
    origin: OriginKind = "arming",
    min_points: int = 10,
    min_reference_m: float = 2.0,
    ground_height_m: float = 0.5,
) -> AlignedTrack:
    if len(track) < min_points:
        raise TooFewPointsError(
            f"'{track.label}' has {len(track)} GPS samples with a fix; at least "
            f"{min_points} are needed to analyse a flight."
        )
    i0 = (
        arming_origin_index(track.armed, track.relative_alt_m, ground_height_m)
        if origin == "arming"
        else 0
    )
    o = (float(track.lat_deg[i0]), float(track.lon_deg[i0]), float(track.alt_m[i0]))
    enu = geodetic_to_enu(track.lat_deg, track.lon_deg, track.alt_m, *o)

    kind: ReferenceKind = "none"
    ref: tuple[float, float] | None = None
    ref_en: Array | None = None
    if reference_latlon is not None:
        kind, ref = "given", reference_latlon
    elif field is not None and field.pad_latlon(reference_pad) is not None:
        kind, ref = "scene", field.pad_latlon(reference_pad)
    if ref is not None:
        ref_en = geodetic_to_enu(ref[0], ref[1], o[2], *o)[:2]
    else:
        dist = np.hypot(enu[:, 0], enu[:, 1])
        armed = np.flatnonzero(track.armed)
        last = int(armed[-1]) if armed.size else len(track) - 1
        if dist[last] >= min_reference_m:
            kind, ref_en = "landing", enu[last, :2]
        elif dist.max() >= min_reference_m:
            kind, ref_en = "farthest", enu[int(np.argmax(dist)), :2]
    rotation = rotation_to(ref_en)
    xyz = rotate_about_up(enu, rotation)
    rel = track.relative_alt_m
    return AlignedTrack(
        track=track,
        xyz_m=xyz,
        origin=o,
        rotation_rad=rotation,
        reference_latlon=ref,
        reference_kind=kind,
        field=field.in_track_frame(o, rotation) if field is not None else None,
        pilot_height_m=np.where(np.isfinite(rel), rel, xyz[:, 2]),
    )
