"""The flight samples of a bare MAVLink telemetry log (`.tlog`: 8-byte big-endian
microsecond timestamp before every packet, as QGroundControl, MAVProxy and our recorder
write), read with `core.mavlink.tlog_records.TlogReader` (which survives a cut or
corrupted log). `analysis.track.load_tlog` makes them a `Track`.

One sample per GPS_RAW_INT with a fix (GLOBAL_POSITION_INT when the log has no raw GPS),
timed by the vehicle's own clock (`time_usec`, `time_boot_ms`; see
`analysis.vehicle_clock`), the receive time only where it has none; the armed state,
relative altitude and speeds are the latest values received before the sample. pymavlink decodes message by message (there is no vectorized MAVLink parser);
everything after the decode is numpy.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from analysis.errors import NoGpsFixError, TrackLoadError
from analysis.vehicle_clock import on_vehicle_clock
from core.mavlink.framing import message_id
from core.mavlink.tlog_records import TlogReader

_WANTED = {
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    mavlink.MAVLINK_MSG_ID_HEARTBEAT,
    mavlink.MAVLINK_MSG_ID_VFR_HUD,
}
_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
_NOT_AUTOPILOT = (mavlink.MAV_TYPE_GCS, mavlink.MAV_TYPE_ONBOARD_CONTROLLER)
_UINT16_UNKNOWN = 65535


def read_tlog_samples(path: Path, min_fix_type: int = 3) -> dict[str, np.ndarray]:
    """The per-sample arrays of a `Track` (its fields from `t_s` to `climb_mps`)."""
    if not path.is_file():
        raise TrackLoadError(f"'{path}' does not exist.")
    gps: list[tuple[float, ...]] = []
    glob: list[tuple[float, ...]] = []
    hb: list[tuple[float, bool]] = []
    rel: list[tuple[float, float]] = []
    hud: list[tuple[float, float, float]] = []
    decoder = mavlink.MAVLink(None)
    decoder.robust_parsing = True
    reader = TlogReader(path)
    try:
        for t, packet in reader:
            # Decode only the four messages analysis reads: a real log holds hundreds of
            # packets per second, and pymavlink's decode is the slow part.
            if message_id(packet) not in _WANTED:
                continue
            try:
                msg = decoder.decode(bytearray(packet))
            except Exception:  # a corrupted packet (bad CRC, cut short): skip it
                continue
            kind = msg.get_type()
            if kind == "GPS_RAW_INT":
                speed = np.nan if msg.vel == _UINT16_UNKNOWN else msg.vel / 100.0
                gps.append(
                    (t, msg.lat * 1e-7, msg.lon * 1e-7, msg.alt / 1000.0, msg.fix_type, speed,
                     msg.time_usec * 1e-6)
                )  # fmt: skip
            elif kind == "GLOBAL_POSITION_INT":
                glob.append(
                    (t, msg.lat * 1e-7, msg.lon * 1e-7, msg.alt / 1000.0, 3, np.nan,
                     msg.time_boot_ms * 1e-3)
                )  # fmt: skip
                rel.append((t, msg.relative_alt / 1000.0))
            elif kind == "HEARTBEAT":
                if msg.type in _NOT_AUTOPILOT or msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
                    continue  # the station's or a companion's own heartbeat
                hb.append((t, bool(msg.base_mode & _ARMED)))
            elif kind == "VFR_HUD":
                hud.append((t, float(msg.groundspeed), float(msg.climb)))
    except OSError as exc:
        raise TrackLoadError(f"'{path}' cannot be read: {exc}") from None

    rows = _by_time(np.array(gps if gps else glob, dtype=np.float64).reshape(-1, 7))
    if rows.shape[0] == 0:
        raise NoGpsFixError(f"'{path}' holds no GPS_RAW_INT or GLOBAL_POSITION_INT message.")
    t, lat, lon, alt, fix, speed, t_vehicle = rows.T
    ok = (fix >= min_fix_type) & ~((lat == 0) & (lon == 0))
    if not ok.any():
        raise NoGpsFixError(f"'{path}' has no GPS sample with a fix (fix_type >= {min_fix_type}).")
    t, lat, lon, alt, fix, speed, t_vehicle = (
        a[ok] for a in (t, lat, lon, alt, fix, speed, t_vehicle)
    )
    # When each sample was taken (the vehicle's clock on the receive clock); the other
    # messages are matched by receive time, as the station saw them arrive.
    taken = on_vehicle_clock(t, t_vehicle)
    order = np.argsort(taken, kind="stable")
    taken, t, lat, lon, alt, fix, speed = (a[order] for a in (taken, t, lat, lon, alt, fix, speed))
    t0 = taken[0]
    hud_a = _by_time(np.array(hud, dtype=np.float64).reshape(-1, 3))
    if np.isnan(speed).all() and hud_a.shape[0]:
        speed = _latest(hud_a[:, 0], hud_a[:, 1], t)
    return {
        "t_s": taken - t0,
        "wall_time": taken,
        "lat_deg": lat,
        "lon_deg": lon,
        "alt_m": alt,
        "fix_type": fix.astype(np.int16),
        "armed": _latest_bool(hb, t),
        "relative_alt_m": _latest(*_cols(rel, 2), t),
        "ground_speed_mps": speed,
        "climb_mps": _latest(hud_a[:, 0], hud_a[:, 2], t),
    }


def _by_time(a: np.ndarray) -> np.ndarray:
    """Rows sorted by their receive time (column 0). A tlog stamps packets with the wall
    clock, which can step back (NTP on a Pi without a real-time clock)."""
    if a.shape[0] > 1 and np.any(np.diff(a[:, 0]) < 0):
        return a[np.argsort(a[:, 0], kind="stable")]
    return a


def _cols(rows: list[tuple[float, float]], n: int) -> tuple[np.ndarray, ...]:
    return tuple(_by_time(np.array(rows, dtype=np.float64).reshape(-1, n)).T)


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
    a = _by_time(np.array(rows, dtype=np.float64))
    v = _latest(a[:, 0], a[:, 1], t)
    return np.nan_to_num(v, nan=0.0) > 0.5
