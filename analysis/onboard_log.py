"""The autopilot's own log (the session's `onboard.ulg` or `onboard.bin`), read onto the
session clock.

One reader for both formats: pyulog for a PX4 ULog, pymavlink's DFReader for an
ArduPilot DataFlash log. Each gives the same streams, in the body's FRD axes and SI
units, stamped in seconds of the vehicle's boot clock (ULog `timestamp`, DataFlash
`TimeUS`):

| stream | columns | ULog topic | DataFlash |
| --- | --- | --- | --- |
| `imu` | `gyro_{x,y,z}_rad_s`, `accel_{x,y,z}_m_s2` | sensor_combined | IMU (the first IMU) |
| `attitude` | `roll_rad`, `pitch_rad`, `yaw_rad` | vehicle_attitude | ATT (degrees) |
| `rates` | `{roll,pitch,yaw}_rad_s` | vehicle_angular_velocity | RATE `R,P,Y`, else IMU's gyro |
| `rates_setpoint` | `{roll,pitch,yaw}_rad_s` | vehicle_rates_setpoint | RATE `RDes,PDes,YDes`, else PIDR/PIDP/PIDY `Tar` (`Des` before ArduCopter 4) |
| `motors` | `motor_{0..3}` (0..1 commands; DataFlash: PWM µs) | actuator_motors | RCOU `C1..C4` |
| `rc` | `ch_{0..7}_us` | input_rc | RCIN `C1..C8` |

Streams a log lacks are absent. The log's boot times go on the session clock through
the session's vehicle clock (session.json `clock.vehicle_boot`, measured by TIMESYNC:
`companion.timesync`); a session whose vehicle never answered gets a line fitted through
its telemetry's ATTITUDE placed by the shortest delay (`analysis.vehicle_clock`). Either
way `alignment` checks the result against the link: the ATTITUDE the tlog carried
against the log's attitude, in ms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel

from fpv_station.analysis.recording import Recording, open_recording, read_columns
from fpv_station.analysis.vehicle_clock import on_vehicle_clock, vehicle_boot_clock
from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import read_meta, write_meta
from fpv_station.companion.timesync import VehicleClock

Array = NDArray[np.float64]
LogFormat = Literal["ulog", "dataflash"]
ONBOARD_FILES = ("onboard.ulg", "onboard.bin")
_DEG = math.pi / 180.0
# How far the log's attitude may lie from the tlog's, searched for the best match (ms).
MAX_LAG_MS = 500


class OnboardLogError(Exception):
    """The onboard log cannot be read; the message says which file and why."""


@dataclass(frozen=True)
class Stream:
    boot_s: Array  # the vehicle's boot clock (s), ascending
    columns: dict[str, Array] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.boot_s.size)

    @property
    def rate_hz(self) -> float:
        """The median sample rate."""
        d = np.diff(self.boot_s)
        d = d[d > 0]
        return float(1.0 / np.median(d)) if d.size else 0.0


@dataclass(frozen=True)
class OnboardLog:
    path: Path
    format: LogFormat
    streams: dict[str, Stream]


def find_onboard_log(folder: Path) -> Path | None:
    """The session folder's onboard log, if it has one."""
    for name in ONBOARD_FILES:
        if (folder / name).is_file():
            return folder / name
    return None


def read_onboard_log(path: Path) -> OnboardLog:
    head = path.read_bytes()[:16] if path.is_file() else b""
    try:
        if head.startswith(b"ULog\x01\x12\x35"):
            return OnboardLog(path, "ulog", _checked(path, _read_ulog(path)))
        if head.startswith(b"\xa3\x95"):
            return OnboardLog(path, "dataflash", _checked(path, _read_dataflash(path)))
    except OnboardLogError:
        raise
    except Exception as exc:  # the parsers raise anything on a damaged file
        raise OnboardLogError(f"'{path}' cannot be read: {type(exc).__name__}: {exc}") from None
    raise OnboardLogError(f"'{path}' is neither a ULog nor a DataFlash log.")


def _checked(path: Path, streams: dict[str, Stream]) -> dict[str, Stream]:
    if not any(len(s) for s in streams.values()):
        raise OnboardLogError(
            f"'{path}' holds none of the IMU, attitude, rate, motor or RC messages read."
        )
    return streams


def _stream(boot_us: np.ndarray, **columns: np.ndarray) -> Stream:
    t = np.asarray(boot_us, dtype=np.float64) * 1e-6
    order = np.argsort(t, kind="stable")
    return Stream(t[order], {k: np.asarray(v, dtype=np.float64)[order] for k, v in columns.items()})


def _read_ulog(path: Path) -> dict[str, Stream]:
    from pyulog import ULog

    topics = [
        "sensor_combined",
        "vehicle_attitude",
        "vehicle_angular_velocity",
        "vehicle_rates_setpoint",
        "actuator_motors",
        "input_rc",
    ]
    ulog = ULog(str(path), topics)
    data = {d.name: d.data for d in ulog.data_list if d.multi_id == 0}
    out: dict[str, Stream] = {}
    if (d := data.get("sensor_combined")) is not None:
        out["imu"] = _stream(
            d["timestamp"],
            **{f"gyro_{a}_rad_s": d[f"gyro_rad[{i}]"] for i, a in enumerate("xyz")},
            **{f"accel_{a}_m_s2": d[f"accelerometer_m_s2[{i}]"] for i, a in enumerate("xyz")},
        )
    if (d := data.get("vehicle_attitude")) is not None:
        roll, pitch, yaw = _euler(*(d[f"q[{i}]"] for i in range(4)))
        out["attitude"] = _stream(d["timestamp"], roll_rad=roll, pitch_rad=pitch, yaw_rad=yaw)
    if (d := data.get("vehicle_angular_velocity")) is not None:
        out["rates"] = _stream(
            d["timestamp"], **{f"{a}_rad_s": d[f"xyz[{i}]"] for i, a in enumerate(_AXES)}
        )
    if (d := data.get("vehicle_rates_setpoint")) is not None:
        out["rates_setpoint"] = _stream(d["timestamp"], **{f"{a}_rad_s": d[a] for a in _AXES})
    if (d := data.get("actuator_motors")) is not None:
        n = sum(1 for k in d if k.startswith("control["))
        out["motors"] = _stream(
            d["timestamp"], **{f"motor_{i}": d[f"control[{i}]"] for i in range(min(n, 8))}
        )
    if (d := data.get("input_rc")) is not None:
        n = sum(1 for k in d if k.startswith("values["))
        out["rc"] = _stream(
            d["timestamp"], **{f"ch_{i}_us": d[f"values[{i}]"] for i in range(min(n, 8))}
        )
    return out


_AXES = ("roll", "pitch", "yaw")


def _read_dataflash(path: Path) -> dict[str, Stream]:
    from pymavlink import DFReader

    wanted = {"IMU", "ATT", "RATE", "PIDR", "PIDP", "PIDY", "RCOU", "RCIN"}
    rows: dict[str, list[dict]] = {k: [] for k in wanted}
    reader = DFReader.DFReader_binary(str(path), zero_time_base=True)
    while (m := reader.recv_match(type=list(wanted))) is not None:
        d = m.to_dict()
        if m.get_type() == "IMU" and d.get("I", 0) != 0:
            continue  # the first IMU only (ArduPilot 4 logs every IMU as IMU, instance I)
        rows[m.get_type()].append(d)

    def col(kind: str, name: str) -> np.ndarray:
        return np.array([r.get(name, np.nan) for r in rows[kind]], dtype=np.float64)

    out: dict[str, Stream] = {}
    if rows["IMU"]:
        out["imu"] = _stream(
            col("IMU", "TimeUS"),
            **{f"gyro_{a}_rad_s": col("IMU", f"Gyr{a.upper()}") for a in "xyz"},
            **{f"accel_{a}_m_s2": col("IMU", f"Acc{a.upper()}") for a in "xyz"},
        )
    if rows["ATT"]:
        out["attitude"] = _stream(
            col("ATT", "TimeUS"),
            roll_rad=col("ATT", "Roll") * _DEG,
            pitch_rad=col("ATT", "Pitch") * _DEG,
            yaw_rad=np.unwrap(col("ATT", "Yaw") * _DEG),
        )
    if rows["RATE"]:
        t = col("RATE", "TimeUS")
        out["rates"] = _stream(
            t, **{f"{a}_rad_s": col("RATE", k) * _DEG for a, k in zip(_AXES, "RPY")}
        )
        out["rates_setpoint"] = _stream(
            t, **{f"{a}_rad_s": col("RATE", f"{k}Des") * _DEG for a, k in zip(_AXES, "RPY")}
        )
    else:
        if "imu" in out:
            imu = out["imu"]
            out["rates"] = Stream(
                imu.boot_s,
                {f"{a}_rad_s": imu.columns[f"gyro_{x}_rad_s"] for a, x in zip(_AXES, "xyz")},
            )
        pid = [rows[k] for k in ("PIDR", "PIDP", "PIDY")]
        if all(pid) and len({len(p) for p in pid}) == 1:
            key = "Tar" if "Tar" in pid[0][0] else "Des"
            out["rates_setpoint"] = _stream(
                col("PIDR", "TimeUS"),
                **{
                    f"{a}_rad_s": col(k, key) * _DEG
                    for a, k in zip(_AXES, ("PIDR", "PIDP", "PIDY"))
                },
            )
    if rows["RCOU"]:
        out["motors"] = _stream(
            col("RCOU", "TimeUS"), **{f"motor_{i}": col("RCOU", f"C{i + 1}") for i in range(4)}
        )
    if rows["RCIN"]:
        out["rc"] = _stream(
            col("RCIN", "TimeUS"), **{f"ch_{i}_us": col("RCIN", f"C{i + 1}") for i in range(8)}
        )
    return out


def _euler(w: Array, x: Array, y: Array, z: Array) -> tuple[Array, Array, Array]:
    """Roll, pitch, yaw (rad) of PX4's FRD-in-NED quaternion (w, x, y, z)."""
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


# -- the session clock ------------------------------------------------------------------


def tlog_attitude(rows_t_s: Array, boot_ms: Array, roll: Array, pitch: Array) -> dict[str, Array]:
    """The telemetry's ATTITUDE samples, one per message (its first row): `t_s` of the
    row that first held it (about when it arrived), its `boot_s`, roll and pitch."""
    ok = np.isfinite(boot_ms) & (boot_ms > 0) & np.isfinite(rows_t_s)
    t, b, r, p = rows_t_s[ok], boot_ms[ok] * 1e-3, roll[ok], pitch[ok]
    new = np.concatenate([[True], np.diff(b) != 0]) if b.size else np.zeros(0, bool)
    return {"t_s": t[new], "boot_s": b[new], "roll": r[new], "pitch": p[new]}


def session_vehicle_clock(meta: dict, attitude: dict[str, Array]) -> VehicleClock | None:
    """The vehicle clock on the session clock: the session's TIMESYNC measure, else a line
    through the telemetry's ATTITUDE placed by the shortest delay; None without either."""
    boot = vehicle_boot_clock(meta)
    if boot is not None:
        return boot
    b, t = attitude["boot_s"], attitude["t_s"]
    if b.size < 2 or np.ptp(b) <= 0:
        return None
    placed = on_vehicle_clock(t, b)
    rate, offset = np.polyfit(b, placed, 1)
    residual = placed - (offset + rate * b)
    return VehicleClock(
        method="delay",
        reason="no TIMESYNC answer: a line through the telemetry's ATTITUDE placed by "
        "the shortest delay",
        offset_s=round(float(offset), 6),
        drift_ppm=round((float(rate) - 1.0) * 1e6, 3),
        residual_ms=round(float(np.sqrt(np.mean(residual**2))) * 1e3, 3),
        span_s=round(float(np.ptp(b)), 3),
    )


class OnboardAlignment(BaseModel):
    """How the onboard log sits on the session clock (session.json `onboard_alignment`)."""

    file: str  # onboard.ulg or onboard.bin
    format: LogFormat
    clock: str  # the mapping used: "timesync" or "delay" (VehicleClock.method)
    start_s: float | None = None  # the log's span on the session clock
    end_s: float | None = None
    rates_hz: dict[str, float] = {}  # each stream's median rate
    # The log's attitude against the tlog's ATTITUDE, both on the vehicle's clock: the
    # shift (ms) that matches them best (0: the two agree), and the RMS angle left.
    attitude_lag_ms: float | None = None
    attitude_rms_deg: float | None = None
    attitude_samples: int = 0
    # ATTITUDE's arrival (the first row holding it) after the log says it was made, on
    # the session clock: the link's delay if the mapping is right (never below 0 by
    # more than the mapping's error).
    arrival_delay_ms_min: float | None = None
    arrival_delay_ms_median: float | None = None
    reason: str | None = None  # why a figure is missing


def align(
    log: OnboardLog, boot: VehicleClock | None, attitude: dict[str, Array]
) -> OnboardAlignment:
    """Where the log lies on the session clock, and how well it agrees with the tlog."""
    out = OnboardAlignment(
        file=log.path.name,
        format=log.format,
        clock=boot.method if boot is not None else "none",
        rates_hz={k: round(s.rate_hz, 1) for k, s in log.streams.items()},
    )
    spans = [s.boot_s for s in log.streams.values() if len(s)]
    if boot is None or not spans:
        why = "no vehicle clock for the session" if boot is None else "the log holds no stream"
        return out.model_copy(update={"reason": why})
    lo = min(float(s[0]) for s in spans)
    hi = max(float(s[-1]) for s in spans)
    update: dict = {
        "start_s": round(float(boot.station_s(lo)), 4),
        "end_s": round(float(boot.station_s(hi)), 4),
    }
    att = log.streams.get("attitude")
    b = attitude["boot_s"]
    inside = (b >= lo) & (b <= hi) if att is not None else np.zeros(b.size, bool)
    if att is None or inside.sum() < 3:
        update["reason"] = "the tlog's ATTITUDE and the log's attitude do not overlap"
        return out.model_copy(update=update)
    b, t = b[inside], attitude["t_s"][inside]
    want = np.column_stack([attitude["roll"][inside], attitude["pitch"][inside]])
    lags = np.arange(-MAX_LAG_MS, MAX_LAG_MS + 1) * 1e-3
    ab, ar, ap = att.boot_s, att.columns["roll_rad"], att.columns["pitch_rad"]
    err = np.empty(lags.size)
    for k, lag in enumerate(lags):  # a thousand vectorized interpolations, not per sample
        x = b + lag
        err[k] = np.mean(
            (np.interp(x, ab, ar) - want[:, 0]) ** 2 + (np.interp(x, ab, ap) - want[:, 1]) ** 2
        )
    best = int(np.argmin(err))
    delay = t - boot.station_s(b)
    update |= {
        "attitude_lag_ms": round(float(lags[best]) * 1e3, 1),
        "attitude_rms_deg": round(math.degrees(math.sqrt(float(err[best]) / 2)), 4),
        "attitude_samples": int(b.size),
        "arrival_delay_ms_min": round(float(delay.min()) * 1e3, 2),
        "arrival_delay_ms_median": round(float(np.median(delay)) * 1e3, 2),
    }
    return out.model_copy(update=update)


def on_session_clock(stream: Stream, boot: VehicleClock) -> Array:
    """The stream's times on the session clock (s)."""
    return boot.station_s(stream.boot_s)


# -- a session's onboard log ------------------------------------------------------------

ATTITUDE_COLUMNS = ("attitude.time_boot_ms", "attitude.roll_rad", "attitude.pitch_rad")


@dataclass(frozen=True)
class SessionOnboard:
    log: OnboardLog
    clock: VehicleClock | None  # the vehicle's clock on the session clock
    alignment: OnboardAlignment

    def t_s(self, stream: str) -> Array:
        """A stream's times on the session clock (NaN without a vehicle clock)."""
        s = self.log.streams[stream]
        return s.boot_s * np.nan if self.clock is None else self.clock.station_s(s.boot_s)


def session_onboard(rec: Recording) -> SessionOnboard | None:
    """The recording's onboard log on its session clock; None when it has none."""
    path = find_onboard_log(rec.folder)
    if path is None:
        return None
    log = read_onboard_log(path)
    if all(c in rec.columns for c in ATTITUDE_COLUMNS):
        t_s, cols = rec.t_s, rec.columns
    else:
        t_s, _, cols = read_columns(rec.telemetry_csv, ATTITUDE_COLUMNS, rec.source)
    att = tlog_attitude(t_s, *(cols[c] for c in ATTITUDE_COLUMNS))
    boot = session_vehicle_clock(rec.meta, att)
    return SessionOnboard(log, boot, align(log, boot, att))


def write_alignment(folder: Path) -> OnboardAlignment | None:
    """Read the session folder's onboard log onto its clock and record how it lies in
    session.json (`onboard_alignment`); None when the session has no onboard log."""
    with open_recording(folder, columns=ATTITUDE_COLUMNS, frames=False) as rec:
        onboard = session_onboard(rec)
    if onboard is None:
        return None
    path = folder / layout.SESSION_JSON
    meta = read_meta(path)
    write_meta(path, meta.model_copy(update={"onboard_alignment": onboard.alignment.model_dump()}))
    return onboard.alignment
