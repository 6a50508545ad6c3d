"""A recording opened for learning exports: the telemetry columns the exporters need, on
the session clock, the camera frames by their recorded times, and the raw MAVLink log.

Inputs are what `fpv-station analyze` takes: a session folder (the recorder's format,
`docs/SESSION_FORMAT.md`), a downloaded session zip (unpacked into a temporary folder
while it is open), or a bare `.tlog`. A tlog has no telemetry.csv: its packets go
through the link's own `StateTracker`, sampled at `TLOG_ROW_HZ` on the log's clock, so
both give the same columns. Recordings are opened one at a time and closed after use,
so an export's memory does not grow with the number of sessions.
"""

from __future__ import annotations

import contextlib
import tempfile
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from operator import attrgetter
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from analysis.csvcols import CsvColumns, to_float
from analysis.track import parse_meta
from companion.recording import frame_pack, layout
from companion.state_tracker import StateTracker
from core.mavlink.tlog_records import TlogReader

Array = NDArray[np.float64]

TLOG_ROW_HZ = 30.0  # the recorder's default row rate
RC_CHANNELS = 18

# The telemetry columns the exporters read (telemetry.csv names); missing ones are NaN.
COLUMNS: tuple[str, ...] = (
    "heartbeat.armed",
    "gps.lat_deg",
    "gps.lon_deg",
    "gps.alt_m",
    "gps.fix_type",
    "global_position.lat_deg",
    "global_position.lon_deg",
    "global_position.alt_m",
    "global_position.relative_alt_m",
    "global_position.vx_mps",
    "global_position.vy_mps",
    "global_position.vz_mps",
    "altitude.relative_alt_m",
    "attitude.roll_rad",
    "attitude.pitch_rad",
    "attitude.yaw_rad",
    "attitude.rollspeed_rad_s",
    "attitude.pitchspeed_rad_s",
    "attitude.yawspeed_rad_s",
    "battery.remaining_pct",
    "vfr_hud.climb_mps",
    *(f"rc.pwm_us.{i}" for i in range(RC_CHANNELS)),
)


class RecordingError(ValueError):
    """A recording that cannot be exported, with a message for the user."""


@dataclass(frozen=True)
class CameraFrames:
    """The frames written for one camera whose bytes are on disk, in capture order (its
    frames.csv; the bytes in its frames.mjpeg, or a file each in a format 1 session)."""

    name: str
    index: frame_pack.FrameIndex
    width: int
    height: int

    @property
    def seq(self) -> NDArray[np.int64]:
        return self.index.seq

    @property
    def t_s(self) -> Array:
        """Capture times, session clock."""
        return self.index.t_s

    def __len__(self) -> int:
        return len(self.index)


@dataclass
class Recording:
    name: str  # the session id, or the file's stem
    source: str  # what the user gave
    folder: Path | None  # the session folder (None for a bare tlog)
    tlog: Path | None
    meta: dict
    t_s: Array  # row times, session clock (s)
    wall_time: Array
    columns: dict[str, Array]
    cameras: dict[str, CameraFrames] = field(default_factory=dict)

    def column(self, name: str) -> Array:
        return self.columns[name]

    def frame_bytes(self, camera: str, k: int) -> bytes:
        """The recorded JPEG bytes of frame `k` (an index into `cameras[camera]`)."""
        return frame_pack.frame_bytes(self.folder, self.cameras[camera].index, k)


def recording_meta(path: str | Path) -> dict:
    """Only the session.json of a session folder or zip ({} for a bare tlog, or a session
    without one): what a caller needs to know before it opens recordings, without reading
    their telemetry or unpacking a zip."""
    p = Path(path)
    if p.is_dir():
        meta_file = p / layout.SESSION_JSON
        return parse_meta(meta_file.read_bytes()) if meta_file.is_file() else {}
    if p.suffix.lower() == ".zip":
        try:
            with zipfile.ZipFile(p) as zf:
                # The shallowest session.json, as _unzip picks the session's folder.
                names = [n for n in zf.namelist() if Path(n).name == layout.SESSION_JSON]
                if not names:
                    return {}
                return parse_meta(zf.read(min(names, key=lambda n: n.count("/"))))
        except (zipfile.BadZipFile, OSError) as exc:
            raise RecordingError(f"'{p}' is not a readable zip: {exc}") from None
    if not p.exists():
        raise RecordingError(f"'{p}' does not exist; give a session folder, zip or .tlog.")
    return {}


@contextlib.contextmanager
def open_recording(path: str | Path) -> Iterator[Recording]:
    """Open a session folder, session zip or bare tlog for the duration of a `with`."""
    p = Path(path)
    if not p.exists():
        raise RecordingError(f"'{p}' does not exist; give a session folder, zip or .tlog.")
    if p.is_dir():
        yield _read_session(p, str(p))
    elif p.suffix.lower() == ".zip":
        with tempfile.TemporaryDirectory(prefix="fpv-export-") as tmp:
            yield _read_session(_unzip(p, Path(tmp)), str(p))
    elif p.suffix.lower() == ".tlog":
        yield _read_tlog(p, str(p), None, {})
    else:
        raise RecordingError(f"'{p}' is not a session folder, .zip or .tlog.")


def _unzip(zip_path: Path, into: Path) -> Path:
    """Unpack a session zip; returns the folder that holds its session files."""
    try:
        with zipfile.ZipFile(zip_path) as zf:
            for name in zf.namelist():
                target = (into / name).resolve()
                if not target.is_relative_to(into.resolve()):
                    raise RecordingError(f"'{zip_path}' has an unsafe member path '{name}'.")
            zf.extractall(into)
    except (zipfile.BadZipFile, OSError) as exc:
        raise RecordingError(f"'{zip_path}' is not a readable zip: {exc}") from None
    marks = sorted(
        (
            f.parent
            for f in into.rglob("*")
            if f.name in (layout.TELEMETRY_CSV, layout.SESSION_JSON)
        ),
        key=lambda d: len(d.parts),
    )
    if marks:
        return marks[0]
    tlogs = sorted(into.rglob("*.tlog"), key=lambda f: len(f.parts))
    if tlogs:
        return tlogs[0].parent
    raise RecordingError(f"'{zip_path}' holds no session (no telemetry.csv or .tlog).")


def _read_session(folder: Path, source: str) -> Recording:
    meta = recording_meta(folder)
    tlog = folder / layout.MAVLINK_TLOG
    if not tlog.is_file():
        tlog = next(iter(sorted(folder.glob("*.tlog"))), None)
    csv_path = folder / layout.TELEMETRY_CSV
    if not csv_path.is_file():
        if tlog is None:
            raise RecordingError(f"'{source}' has neither {layout.TELEMETRY_CSV} nor a .tlog.")
        return _read_tlog(tlog, source, folder, meta)
    t_s, wall, columns = _read_csv(csv_path, source)
    cams = {}
    for cam in meta.get("cameras") or layout.CAMERAS:
        frames = _read_frames_csv(folder, str(cam))
        if frames is not None and len(frames):
            cams[str(cam)] = frames
    name = str(meta.get("id") or folder.name)
    return Recording(name, source, folder, tlog, meta, t_s, wall, columns, cams)


CSV_BLOCK_BYTES = 4 << 20  # telemetry.csv is read in blocks of whole rows this big


def _read_csv(path: Path, source: str) -> tuple[Array, Array, dict[str, Array]]:
    """The columns exporters need, read block by block: memory holds those float columns
    (~6 MB per 10 min at 30 Hz), never the whole file (~60 MB)."""
    names = ("t_s", "wall_time", *COLUMNS)
    parts: dict[str, list[Array]] = {n: [] for n in names}
    with open(path, "rb") as f:
        header = [h.strip().strip('"') for h in f.readline().decode("utf-8", "replace").split(",")]
        index = {n: i for i, n in enumerate(header)}
        if "t_s" not in index:
            raise RecordingError(f"'{source}': telemetry.csv has no t_s column.")
        rest = b""
        while True:
            block = f.read(CSV_BLOCK_BYTES)
            data = rest + block
            cut = data.rfind(b"\n") + 1 if block else len(data)
            body, rest = data[:cut], data[cut:]
            if body:
                table = CsvColumns(body, len(header))
                for n in names:
                    parts[n].append(_float_column(table, index.get(n), source, n))
            if not block:
                break
    columns = {n: np.concatenate(v) if v else np.array([]) for n, v in parts.items()}
    if columns["t_s"].size == 0:
        raise RecordingError(f"'{source}': telemetry.csv has no rows.")
    return columns.pop("t_s"), columns.pop("wall_time"), columns


def _float_column(table: CsvColumns, k: int | None, source: str, name: str) -> Array:
    if k is None:
        return np.full(table.rows, np.nan)
    try:
        return to_float(table.column(k))
    except ValueError as exc:
        raise RecordingError(f"'{source}': column {name}: {exc}") from None


def _read_frames_csv(folder: Path, camera: str) -> CameraFrames | None:
    """The camera's frames whose bytes are on disk (None: no frames.csv, or none)."""
    index = frame_pack.read_index(folder, camera)
    if index is None:
        return None
    index = index.where(frame_pack.on_disk(folder, index) & np.isfinite(index.t_s))
    if not len(index):
        return None
    return CameraFrames(camera, index, int(index.width[0]), int(index.height[0]))


# ---------------------------------------------------------------- bare tlog


_GETTERS = {
    n: attrgetter(n.rsplit(".", 1)[0] if n.startswith("rc.pwm_us.") else n) for n in COLUMNS
}


def _value(state, name: str) -> float:
    v = _GETTERS[name](state)
    if name.startswith("rc.pwm_us."):
        v = v[int(name.rsplit(".", 1)[1])]
    if v is None:
        return np.nan
    return float(v)


def _read_tlog(path: Path, source: str, folder: Path | None, meta: dict) -> Recording:
    """Rows of the state the link would have shown, every 1/TLOG_ROW_HZ of log time."""
    tracker = StateTracker()
    decoder = mavlink.MAVLink(None)
    decoder.robust_parsing = True
    period = 1.0 / TLOG_ROW_HZ
    times: list[float] = []
    rows: list[list[float]] = []
    t0: float | None = None
    next_row = 0.0
    try:
        for t, packet in TlogReader(path):
            if t0 is None:
                t0 = t
                next_row = t
            while t >= next_row:  # rows are the state just before each row instant
                times.append(next_row)
                rows.append([_value(tracker.state, n) for n in COLUMNS])
                next_row += period
            try:
                msg = decoder.decode(bytearray(packet))
            except Exception:  # a corrupted packet (bad CRC, cut short): skip it
                continue
            if msg is not None:
                tracker.update(msg, t)
    except OSError as exc:
        raise RecordingError(f"'{source}' cannot be read: {exc}") from None
    if t0 is None or not rows:
        raise RecordingError(f"'{source}' holds no MAVLink packet.")
    wall = np.array(times)
    table = np.array(rows, dtype=np.float64)
    columns = {n: table[:, i] for i, n in enumerate(COLUMNS)}
    name = str(meta.get("id") or (folder.name if folder else path.stem))
    return Recording(name, source, folder, path, meta, wall - t0, wall, columns)
