"""A flight track as typed numpy columns, loaded from a session folder's `telemetry.csv`,
a downloaded session zip, or a bare `.tlog`.

One sample per GPS solution, timed by the vehicle's clock where the file has it (see
`analysis.vehicle_clock`), and also by the session clock of the first row that holds it
(`row_t_s`: the one time axis that views share with the rows and frames). The recorder
writes one CSV row per telemetry tick (faster than the GPS updates), so the same GPS
solution appears on several rows; counting it several times would weight slow-update
stretches more than others and bias every mean and standard deviation. We keep the first row of each GPS *message*, recognised by a
change of the group's `t_mono` (or `time_usec`) column; only when neither column exists
do we fall back to a change of (lat, lon, alt). Identical coordinates from distinct
messages (a perfect hover) are therefore kept, as they are real samples.

Rows without a fix (`gps.fix_type` < `min_fix_type`, or no coordinates) are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from fpv_station.analysis.csvcols import CsvColumns, to_bool, to_float
from fpv_station.analysis.errors import NoGpsFixError, TrackLoadError
from fpv_station.analysis.recording import open_recording
from fpv_station.analysis.vehicle_clock import on_vehicle_clock, vehicle_boot_clock
from fpv_station.companion.recording import layout
from fpv_station.companion.recording.flags import vehicle_texts
from fpv_station.companion.timesync import VehicleClock

Array = NDArray[np.float64]
PositionSource = Literal["gps", "global_position"]

TELEMETRY_CSV = layout.TELEMETRY_CSV
MIN_FIX_3D = 3


@dataclass(frozen=True)
class Track:
    """One sample per GPS solution, time-ordered. NaN where a value was never reported."""

    label: str  # how tables and plots name this flight ("physical", "twin", folder name)
    source: str  # the file or folder it came from
    t_s: Array  # when the GPS took the sample: vehicle clock placed on the session clock
    wall_time: Array  # Unix time (s) of the sample, NaN if unknown
    lat_deg: Array
    lon_deg: Array
    alt_m: Array  # MSL
    fix_type: NDArray[np.int16]
    armed: NDArray[np.bool_]
    relative_alt_m: Array  # the pilot's altitude (since arming), else the autopilot's
    ground_speed_mps: Array
    climb_mps: Array
    meta: dict = field(default_factory=dict)  # the session's metadata, when it has some
    # Session clock of the first telemetry.csv row holding the sample: at any instant the
    # row shows this sample, and the frames are stamped on this clock (None: `t_s`).
    row_t_s: Array = None  # type: ignore[assignment]  # None: __post_init__ takes t_s
    # The GPS's horizontal uncertainty (m) where the receiver reported it, else NaN.
    h_acc_m: Array = None  # type: ignore[assignment]  # None: __post_init__ fills NaN
    # What the vehicle said (its STATUSTEXTs: session time, text), from the recording's
    # messages.csv or replayed from its tlog (`Recording.vehicle_texts`).
    vehicle_texts: tuple[tuple[float | None, str], ...] = ()

    def __post_init__(self) -> None:
        if self.row_t_s is None:
            object.__setattr__(self, "row_t_s", self.t_s)
        if self.h_acc_m is None:
            object.__setattr__(self, "h_acc_m", np.full(self.t_s.size, np.nan))

    def __len__(self) -> int:
        return int(self.t_s.size)

    def select(self, mask: NDArray[np.bool_] | NDArray[np.intp] | slice) -> Track:
        """The same track restricted to `mask` (boolean or index array, or a slice)."""
        arrays = {name: getattr(self, name)[mask] for name in _ARRAY_FIELDS}
        return replace(self, **arrays)

    @property
    def platform(self) -> str:
        """'twin' when the session says it came from the digital twin, else 'physical'."""
        source = str(self.meta.get("platform") or self.meta.get("source") or "").lower()
        twin = source.startswith(("sim", "twin", "airsim", "digital twin"))
        return "twin" if twin else "physical"


_ARRAY_FIELDS = (
    "t_s",
    "wall_time",
    "lat_deg",
    "lon_deg",
    "alt_m",
    "fix_type",
    "armed",
    "relative_alt_m",
    "ground_speed_mps",
    "climb_mps",
    "row_t_s",
    "h_acc_m",
)


def load_track(
    path: str | Path,
    label: str | None = None,
    position: PositionSource = "gps",
    min_fix_type: int = MIN_FIX_3D,
) -> Track:
    """Load a session folder, a session zip, a `.tlog` (all through
    `analysis.recording.open_recording`) or a bare `telemetry.csv`. A session's own
    `telemetry.csv` is read as its session, on the session's measured vehicle clock."""
    p = Path(path)
    if p.name == layout.TELEMETRY_CSV and (p.parent / layout.SESSION_JSON).is_file():
        p = p.parent
    if p.suffix.lower() == ".csv" and p.is_file():
        name = label or p.parent.name
        track = load_telemetry_csv(p.read_bytes(), name, str(p), position, min_fix_type)
        said = tuple(vehicle_texts(p.parent / layout.MESSAGES_CSV))
        return replace(track, vehicle_texts=said)
    try:
        with open_recording(p, frames=False) as rec:
            name = label or str(rec.meta.get("label") or rec.name)
            raw = rec.telemetry_csv.read_bytes()
            boot = vehicle_boot_clock(rec.meta)
            track = load_telemetry_csv(raw, name, rec.source, position, min_fix_type, boot)
            return replace(track, meta=rec.meta, vehicle_texts=tuple(rec.vehicle_texts()))
    except OSError as exc:
        raise TrackLoadError(f"'{p}' cannot be read: {exc}") from None


def load_session_dir(
    folder: Path,
    label: str | None = None,
    position: PositionSource = "gps",
    min_fix_type: int = MIN_FIX_3D,
) -> Track:
    return load_track(folder, label, position, min_fix_type)


# ---------------------------------------------------------------- telemetry.csv


def load_telemetry_csv(
    raw: bytes,
    label: str,
    source: str,
    position: PositionSource = "gps",
    min_fix_type: int = MIN_FIX_3D,
    boot: VehicleClock | None = None,
) -> Track:
    """Parse the recorder's CSV: only the columns analysis needs, only the first row of
    each GPS message, all vectorized (see `analysis.csvcols`); `boot`: the session's
    measured vehicle clock (`analysis.vehicle_clock.vehicle_boot_clock`)."""
    header_line, _, body = raw.partition(b"\n")
    header = [h.strip().strip('"') for h in header_line.decode("utf-8", "replace").split(",")]
    index = {name: i for i, name in enumerate(header)}
    if "t_s" not in index:
        raise TrackLoadError(
            f"'{source}' is not a telemetry CSV: it needs columns t_s and "
            f"{position}.lat_deg/lon_deg/alt_m."
        )
    table = CsvColumns(body, len(header))
    if table.rows == 0:
        raise NoGpsFixError(f"'{source}' has a header but no telemetry rows.")
    pos = position
    if not _has_values(table, index, f"{pos}.lat_deg"):
        other: PositionSource = "global_position" if pos == "gps" else "gps"
        if _has_values(table, index, f"{other}.lat_deg"):  # fall back to the other source
            pos = other
    need = [f"{pos}.lat_deg", f"{pos}.lon_deg", f"{pos}.alt_m"]
    if any(n not in index for n in need):
        raise TrackLoadError(
            f"'{source}' is not a telemetry CSV: it needs columns t_s and "
            f"{pos}.lat_deg/lon_deg/alt_m."
        )
    wanted = {
        "t_s": ["t_s"],
        "wall_time": ["wall_time"],
        "lat": [f"{pos}.lat_deg"],
        "lon": [f"{pos}.lon_deg"],
        "alt": [f"{pos}.alt_m"],
        # A log without GPS_RAW_INT has no fix type: the fused position stands alone.
        "fix": ["gps.fix_type"] if _has_values(table, index, "gps.lat_deg") else [],
        "key": [f"{pos}.t_mono", f"{pos}.time_usec", f"{pos}.time_boot_ms"],
        "armed": ["heartbeat.armed"],
        "rel": ["altitude.relative_alt_m", "global_position.relative_alt_m"],
        "speed": ["vfr_hud.ground_speed_mps", "gps.ground_speed_mps"],
        "climb": ["vfr_hud.climb_mps"],
        "h_acc": ["gps.h_acc_m"],
        "vehicle_t": [f"{pos}.time_usec", f"{pos}.time_boot_ms"],
    }
    chosen = {k: next((c for c in cands if c in index), None) for k, cands in wanted.items()}
    first = _first_of_each_message(
        table, [index[chosen["key"]]] if chosen["key"] else [index[n] for n in need]
    )

    def column(key: str) -> Array:
        name = chosen[key]
        if name is None:
            return np.full(first.size, np.nan)
        try:
            return to_float(table.column(index[name], first))
        except ValueError as exc:
            raise TrackLoadError(f"'{source}': column {name}: {exc}") from None

    row_t, lat, lon, alt, fix = (column(k) for k in ("t_s", "lat", "lon", "alt", "fix"))
    wall, t_s = column("wall_time"), row_t
    if chosen["vehicle_t"] is not None:  # when the GPS took it, not when a burst brought it
        scale = 1e-6 if chosen["vehicle_t"].endswith("_usec") else 1e-3
        taken = on_vehicle_clock(row_t, column("vehicle_t") * scale, boot)
        wall, t_s = wall + (taken - row_t), taken
    ok = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(alt) & np.isfinite(t_s)
    ok &= ~((lat == 0) & (lon == 0))  # autopilots report 0,0 before a fix
    if chosen["fix"] is not None:
        ok &= np.nan_to_num(fix, nan=0) >= min_fix_type
    if not ok.any():
        raise NoGpsFixError(
            f"'{source}' has no sample with a GPS fix (fix_type >= {min_fix_type}); "
            "was the GPS locked during the flight?"
        )
    armed = (
        to_bool(table.column(index[chosen["armed"]], first))
        if chosen["armed"]
        else np.zeros(first.size, bool)
    )
    return Track(
        label=label,
        source=source,
        t_s=t_s[ok],
        row_t_s=row_t[ok],
        wall_time=wall[ok],
        lat_deg=lat[ok],
        lon_deg=lon[ok],
        alt_m=alt[ok],
        fix_type=np.nan_to_num(fix[ok], nan=MIN_FIX_3D).astype(np.int16),
        armed=armed[ok],
        relative_alt_m=column("rel")[ok],
        ground_speed_mps=column("speed")[ok],
        climb_mps=column("climb")[ok],
        h_acc_m=column("h_acc")[ok],
    )


def _has_values(table: CsvColumns, index: dict[str, int], name: str) -> bool:
    """Whether the column exists and holds a value in some row (a recorder writes every
    column, empty while its message never came)."""
    if name not in index:
        return False
    v = np.char.strip(table.column(index[name]))
    return bool(np.any((v != b"") & (v != b"None") & (v != b"null")))


def _first_of_each_message(table: CsvColumns, key_cols: list[int]) -> NDArray[np.intp]:
    """Row indices where the GPS message changes: its t_mono (or time) column, or else
    its coordinates. Compared as the raw text, before any number parsing."""
    new = np.zeros(table.rows, bool)
    new[0] = True
    for k in key_cols:
        v = table.column(k)
        new[1:] |= v[1:] != v[:-1]
    return np.flatnonzero(new)
