"""A `Track` from a bare MAVLink telemetry log (`.tlog`: 8-byte big-endian microsecond
timestamp before every packet, as QGroundControl, MAVProxy and our recorder write).

One sample per GPS_RAW_INT with a fix (GLOBAL_POSITION_INT when the log has no raw GPS);
the armed state, relative altitude and speeds are the latest values received before the
sample. pymavlink decodes message by message (there is no vectorized MAVLink parser);
everything after the decode is numpy.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pymavlink import mavutil

from analysis.errors import NoGpsFixError, TrackLoadError
from analysis.track import Track

_TYPES = ["GPS_RAW_INT", "GLOBAL_POSITION_INT", "HEARTBEAT", "VFR_HUD"]
_ARMED = mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
_NOT_AUTOPILOT = (mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_TYPE_ONBOARD_CONTROLLER)
_UINT16_UNKNOWN = 65535


def read_tlog(path: Path, label: str, min_fix_type: int = 3) -> Track:
    if not path.is_file():
        raise TrackLoadError(f"'{path}' does not exist.")
    try:
        conn = mavutil.mavlink_connection(str(path), robust_parsing=True)
    except Exception as exc:  # pymavlink raises bare Exceptions on bad files
        raise TrackLoadError(f"'{path}' is not a readable tlog: {exc}") from None
    gps: list[tuple[float, ...]] = []
    glob: list[tuple[float, ...]] = []
    hb: list[tuple[float, bool]] = []
    rel: list[tuple[float, float]] = []
    hud: list[tuple[float, float, float]] = []
    try:
        while True:
            msg = conn.recv_match(type=_TYPES, blocking=False)
            if msg is None:
                break
            t = float(getattr(msg, "_timestamp", 0.0))
            kind = msg.get_type()
            if kind == "GPS_RAW_INT":
                speed = np.nan if msg.vel == _UINT16_UNKNOWN else msg.vel / 100.0
                gps.append((t, msg.lat * 1e-7, msg.lon * 1e-7, msg.alt / 1000.0,
                            msg.fix_type, speed))  # fmt: skip
            elif kind == "GLOBAL_POSITION_INT":
                glob.append((t, msg.lat * 1e-7, msg.lon * 1e-7, msg.alt / 1000.0, 3, np.nan))
                rel.append((t, msg.relative_alt / 1000.0))
            elif kind == "HEARTBEAT":
                if msg.type in _NOT_AUTOPILOT or msg.autopilot == mavutil.mavlink.MAV_AUTOPILOT_INVALID:
                    continue  # the station's or a companion's own heartbeat
                hb.append((t, bool(msg.base_mode & _ARMED)))
            elif kind == "VFR_HUD":
                hud.append((t, float(msg.groundspeed), float(msg.climb)))
    finally:
        conn.close()

    rows = np.array(gps if gps else glob, dtype=np.float64).reshape(-1, 6)
    if rows.shape[0] == 0:
        raise NoGpsFixError(f"'{path}' holds no GPS_RAW_INT or GLOBAL_POSITION_INT message.")
    t, lat, lon, alt, fix, speed = rows.T
    ok = (fix >= min_fix_type) & ~((lat == 0) & (lon == 0))
    if not ok.any():
        raise NoGpsFixError(
            f"'{path}' has no GPS sample with a fix (fix_type >= {min_fix_type})."
        )
    t, lat, lon, alt, fix, speed = (a[ok] for a in (t, lat, lon, alt, fix, speed))
    t0 = t[0]
    hud_a = np.array(hud, dtype=np.float64).reshape(-1, 3)
    if np.isnan(speed).all() and hud_a.shape[0]:
        speed = _latest(hud_a[:, 0], hud_a[:, 1], t)
    return Track(
        label=label,
        source=str(path),
        t_s=t - t0,
        wall_time=t,
        lat_deg=lat,
        lon_deg=lon,
        alt_m=alt,
        fix_type=fix.astype(np.int16),
        armed=_latest_bool(hb, t),
        relative_alt_m=_latest(*_cols(rel, 2), t),
        ground_speed_mps=speed,
        climb_mps=_latest(hud_a[:, 0], hud_a[:, 2], t),
    )


def _cols(rows: list[tuple[float, float]], n: int) -> tuple[np.ndarray, ...]:
    a = np.array(rows, dtype=np.float64).reshape(-1, n)
    return tuple(a.T)


def _latest(t_src: np.ndarray, v_src: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The last value received at or before each time `t` (NaN before the first)."""
    if t_src.size == 0:
        return np.full(t.size, np.nan)
    i = np.searchsorted(t_src, t, side="right") - 1
    out = v_src[np.clip(i, 0, None)].astype(np.float64)
    out[i < 0] = np.nan
    return out


def _latest_bool(rows: list[tuple[float, bool]], t: np.ndarray) -> np.ndarray:
    if not rows:
        return np.zeros(t.size, bool)
    a = np.array(rows, dtype=np.float64)
    v = _latest(a[:, 0], a[:, 1], t)
    return np.nan_to_num(v, nan=0.0) > 0.5
