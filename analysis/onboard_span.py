"""Where the autopilot's own log (onboard.ulg, onboard.bin) lies on the session clock.

The log stamps its samples on the vehicle's boot clock (µs since boot: ULog's
timestamps, DataFlash's TimeUS). The session clock is the recorder's `t_s`. One mapping
puts the first: `vehicle_to_session`, the seam every reader of the log on the session
clock goes through. With the session's measured TIMESYNC mapping (session.json
`clock.vehicle_boot`, method "timesync") it is that line; otherwise the shortest-delay
placement of the telemetry's own vehicle times (`analysis.vehicle_clock`, ATTITUDE's
`time_boot_ms` against its rows' `t_s`), carried to the log's times by the nearest
telemetry sample's offset.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from fpv_station.analysis.recording import open_recording
from fpv_station.analysis.vehicle_clock import on_vehicle_clock

BOOT_COLUMN = "attitude.time_boot_ms"
ToSession = Callable[[np.ndarray], np.ndarray]


def log_boot_span_s(path: Path) -> tuple[float, float] | None:
    """The first and last IMU sample of a ULog or DataFlash log, in seconds of the
    vehicle's boot clock; None when it holds none."""
    if path.suffix == ".ulg":
        from pyulog import ULog

        ulog = ULog(str(path), ["sensor_combined"])
        if ulog.data_list:
            t = ulog.data_list[0].data["timestamp"]
            return float(t[0]) * 1e-6, float(t[-1]) * 1e-6
        if ulog.last_timestamp > ulog.start_timestamp:
            return ulog.start_timestamp * 1e-6, ulog.last_timestamp * 1e-6
        return None
    from pymavlink import DFReader

    reader = DFReader.DFReader_binary(str(path))
    try:
        first = last = None
        while (m := reader.recv_match(type=["IMU"])) is not None:
            last = m.TimeUS
            first = last if first is None else first
    finally:
        reader.close()
    return None if first is None else (first * 1e-6, last * 1e-6)


def vehicle_to_session(folder: Path) -> tuple[ToSession, str] | None:
    """The session's mapping from vehicle boot seconds to `t_s`, and its method
    ("timesync" or "delay"); None when the session has neither."""
    with open_recording(folder, [BOOT_COLUMN], frames=False) as rec:
        boot = (rec.meta.get("clock") or {}).get("vehicle_boot") or {}
        offset, drift = boot.get("offset_s"), boot.get("drift_ppm")
        if boot.get("method") == "timesync" and offset is not None and drift is not None:
            scale = 1.0 + float(drift) * 1e-6
            return (lambda b: float(offset) + np.asarray(b, float) * scale), "timesync"
        t_s, boot_ms = rec.t_s, rec.columns.get(BOOT_COLUMN)
    if boot_ms is None:
        return None
    ok = np.isfinite(boot_ms) & (boot_ms > 0) & np.isfinite(t_s)
    if not ok.any():
        return None
    boot_s = boot_ms[ok] * 1e-3
    # Rows repeat a sample until the next one comes: each sample at its first row.
    first = np.concatenate([[True], np.diff(boot_s) != 0])
    boot_s, placed = boot_s[first], on_vehicle_clock(t_s[ok][first], boot_s[first])
    offsets = placed - boot_s

    def to_session(b: np.ndarray) -> np.ndarray:
        b = np.asarray(b, float)
        i = np.clip(np.searchsorted(boot_s, b), 0, boot_s.size - 1)
        return b + offsets[i]

    return to_session, "delay"


def span_on_session_clock(folder: Path, log_path: Path) -> dict | None:
    """The log's span on the session clock, for session.json `onboard_log`: `t_s`
    [first, last], `boot_s` [first, last] and the mapping's `clock` method; None when
    the log has no IMU samples or the session no vehicle times."""
    span = log_boot_span_s(log_path)
    if span is None:
        return None
    mapping = vehicle_to_session(folder)
    if mapping is None:
        return {"boot_s": [round(v, 6) for v in span], "t_s": None, "clock": None}
    to_session, method = mapping
    t = to_session(np.array(span))
    return {
        "boot_s": [round(v, 6) for v in span],
        "t_s": [round(float(v), 6) for v in t],
        "clock": method,
    }
