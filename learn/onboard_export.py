"""The autopilot's own log in the exports: its high-rate streams (`analysis.onboard_log`:
IMU, attitude, rates and their setpoints, motor outputs, RC) at their native rates, on
the session clock of the frames.

- MCAP: one JSON channel per stream, `/onboard/<stream>`, a message per sample at its
  time (the same Unix-shifted session clock as the frames and rows).
- LeRobot: per episode, each stream's full-rate series as
  `onboard/chunk-000/episode_<index>/<stream>.parquet` (`session_time_s`, `timestamp`
  since the episode's first frame, the vehicle's `boot_s`, then the stream's columns),
  and `frame_windows.parquet`: for every frame, per stream, the rows `[from, to)` of that
  series sampled since the frame before (`<stream>.from`, `<stream>.to`): the window of
  high-rate samples that led up to the frame.

A recording whose onboard log cannot be read is exported without these, with a warning.
"""

from __future__ import annotations

import heapq
import logging
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fpv_station.analysis.onboard_log import OnboardLogError, SessionOnboard, session_onboard
from fpv_station.analysis.recording import Recording

log = logging.getLogger(__name__)

ONBOARD_DIR = "onboard/chunk-000/episode_{episode_index:06d}"


_last: tuple[str, SessionOnboard | None] | None = None  # this process's latest read


def onboard_of(rec: Recording) -> SessionOnboard | None:
    """The recording's onboard log on its session clock, read once for all its episodes
    (an export job takes one recording's episodes in turn); None: it has none usable."""
    global _last
    key = f"{rec.source}|{rec.folder}"
    if _last is None or _last[0] != key:
        try:
            onboard = session_onboard(rec)
        except OnboardLogError as exc:
            log.warning("%s: exported without its onboard log: %s", rec.name, exc)
            onboard = None
        if onboard is not None and onboard.clock is None:
            log.warning("%s: its onboard log has no place on the session clock", rec.name)
            onboard = None
        _last = (key, onboard)
    return _last[1]


@dataclass(frozen=True)
class OnboardSeries:
    """An episode's onboard series written as part files (`series_part`), moved into the
    dataset by the assembler (`place_series`), which alone knows the episode's index."""

    folder: Path
    rates_hz: dict[str, float]


def series_part(
    rec: Recording, frame_t_s: np.ndarray, parts: Path, tag: str
) -> OnboardSeries | None:
    """The episode's series (frames at `frame_t_s`) under `parts/{tag}_onboard`."""
    onboard = onboard_of(rec)
    if onboard is None or frame_t_s.size == 0:
        return None
    folder = Path(parts) / f"{tag}_onboard"
    rows = write_lerobot_series(folder, onboard, frame_t_s)
    rates = {k: onboard.log.streams[k].rate_hz for k, n in rows.items() if n}
    return OnboardSeries(folder, rates)


def place_series(root: Path, episode_index: int, series: OnboardSeries) -> None:
    target = root / ONBOARD_DIR.format(episode_index=episode_index)
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.move(str(series.folder), str(target))


def onboard_events(
    onboard: SessionOnboard, t_lo: float, t_hi: float, wall0: float
) -> Iterator[tuple[int, str, tuple[str, dict]]]:
    """`(log time ns, "onboard", (stream, message))` of every sample from `t_lo` to
    `t_hi` on the session clock, in time order."""
    per_stream = []
    for name, stream in onboard.log.streams.items():
        t = onboard.t_s(name)
        keep = np.flatnonzero((t >= t_lo) & (t <= t_hi))
        per_stream.append(_samples(name, stream.columns, stream.boot_s, t, keep, wall0))
    return heapq.merge(*per_stream, key=lambda e: e[0])


def _samples(name, columns, boot_s, t, keep, wall0):
    for i in keep:
        msg = {"t_s": float(t[i]), "boot_s": float(boot_s[i])}
        msg.update({k: _num(v[i]) for k, v in columns.items()})
        yield int(round((wall0 + t[i]) * 1e9)), "onboard", (name, msg)


def write_lerobot_series(
    folder: Path, onboard: SessionOnboard, frame_t_s: np.ndarray
) -> dict[str, int]:
    """The episode's full-rate series and per-frame windows in `folder`; returns the
    rows written per stream."""
    folder.mkdir(parents=True, exist_ok=True)
    t0, t1 = float(frame_t_s[0]), float(frame_t_s[-1])
    windows: dict[str, pa.Array] = {"frame_index": pa.array(np.arange(frame_t_s.size))}
    rows: dict[str, int] = {}
    for name, stream in onboard.log.streams.items():
        t = onboard.t_s(name)
        keep = np.flatnonzero((t > t0 - _first_window(frame_t_s)) & (t <= t1))
        ts = t[keep]
        table = {
            "session_time_s": ts,
            "timestamp": ts - t0,
            "boot_s": stream.boot_s[keep],
            **{k: v[keep] for k, v in stream.columns.items()},
        }
        pq.write_table(pa.table(table), folder / f"{name}.parquet", compression="snappy")
        # Frame k's window: the samples after frame k-1's instant, up to frame k's.
        to = np.searchsorted(ts, frame_t_s, side="right")
        windows[f"{name}.from"] = pa.array(np.concatenate([[0], to[:-1]]).astype(np.int64))
        windows[f"{name}.to"] = pa.array(to.astype(np.int64))
        rows[name] = int(keep.size)
    pq.write_table(pa.table(windows), folder / "frame_windows.parquet", compression="snappy")
    return rows


def _first_window(frame_t_s: np.ndarray) -> float:
    """The first frame's window: as long as the frames' median spacing."""
    d = np.diff(frame_t_s)
    return float(np.median(d)) if d.size else 0.0


def _num(v: float) -> float | None:
    return None if not np.isfinite(v) else float(v)


LEROBOT_CARD = """
## The autopilot's own log

Recordings that hold the autopilot's flight log (`onboard.ulg`, `onboard.bin`) add its
high-rate streams, on the frames' clock (`session_time_s`): per episode,
`onboard/chunk-000/episode_<index>/<stream>.parquet` holds a stream at its native rate
(`session_time_s`, `timestamp` since the episode's first frame, the vehicle's boot time
`boot_s`, then its columns), and `frame_windows.parquet` gives, for each `frame_index`,
the rows `[<stream>.from, <stream>.to)` of each stream sampled since the frame before.

| stream | columns (body FRD, SI units) | rate here |
| --- | --- | --- |
{rows}
"""

STREAM_COLUMNS = {
    "imu": "`gyro_{x,y,z}_rad_s`, `accel_{x,y,z}_m_s2`",
    "attitude": "`roll_rad`, `pitch_rad`, `yaw_rad`",
    "rates": "`{roll,pitch,yaw}_rad_s`",
    "rates_setpoint": "`{roll,pitch,yaw}_rad_s` (the rate controller's targets)",
    "motors": "`motor_{0..3}` (commands 0..1; DataFlash: PWM µs)",
    "rc": "`ch_{0..7}_us`",
}


def lerobot_card_section(rates_hz: dict[str, float]) -> str:
    """The dataset card's section on the onboard streams ('' when none was exported)."""
    if not rates_hz:
        return ""
    rows = "\n".join(
        f"| `{name}` | {STREAM_COLUMNS.get(name, '')} | {hz:.0f} Hz |"
        for name, hz in sorted(rates_hz.items())
    )
    return LEROBOT_CARD.format(rows=rows)
