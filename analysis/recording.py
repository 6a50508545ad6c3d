"""The one reader of a recording: a session folder (the recorder's format,
`docs/SESSION_FORMAT.md`), a downloaded session zip, or a bare `.tlog`. Analysis
(`analysis.track`), the exports and the learning evaluation all open recordings here.

A recording's telemetry is always a telemetry.csv, and what the vehicle said (its
STATUSTEXTs: a crash, a failsafe) a messages.csv. A tlog without them (a bare tlog, or a
session whose rows were lost) is replayed through the link's own `StateTracker` and
sampled by the recorder's own `RowFormatter` and `message_rows`, at the session's row
rate, on the log's clock, into a temporary telemetry.csv and messages.csv: the same
decoder, the same columns and the same rows as a live recording, so a flight reads the
same from either file, its crash included. A zip is unpacked
into a temporary folder (its camera frames only when they are asked for). Both live as
long as the `with` block; recordings are opened one at a time and closed after use, so
an export's memory does not grow with the number of sessions.

A tlog that is a session's own (`mavlink.tlog` beside its session.json) carries that
session's metadata: the same flight, its task and platform, read from the other file.
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import tempfile
import zipfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20.ardupilotmega import MAVError, MAVLink_unknown

from fpv_station.analysis.csvcols import CsvColumns, to_float
from fpv_station.analysis.errors import TrackLoadError
from fpv_station.companion.recording import frame_pack, layout
from fpv_station.companion.recording.flags import vehicle_texts
from fpv_station.companion.recording.rows import RowFormatter, Sample, message_rows
from fpv_station.companion.state_tracker import StateTracker
from fpv_station.core.mavlink.fast_decode import FastDecoder
from fpv_station.core.mavlink.tlog_records import TlogReader

Array = NDArray[np.float64]

DEFAULT_ROW_HZ = 30.0  # the recorder's default row rate, for a tlog of no session
META_FILES = (layout.SESSION_JSON, "meta.json", "metadata.json")
FILL_GAP_S = 60.0  # a tlog's silence longer than this gets no rows (`replay_tlog`)
CSV_BLOCK_BYTES = 4 << 20  # telemetry.csv columns are read in blocks of whole rows this big


class RecordingError(TrackLoadError):
    """A recording that cannot be opened or read, with a message for the user."""


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
    folder: Path  # the session's files (a temporary folder for a zip or a bare tlog)
    telemetry_csv: Path  # recorded, or replayed from the tlog (`from_tlog`)
    tlog: Path | None
    meta: dict
    from_tlog: bool  # the telemetry was replayed from the tlog
    messages_csv: Path | None = None  # recorded, or replayed from the tlog; None: neither
    # The columns asked for at open (float, NaN where empty), on the session clock.
    t_s: Array = field(default_factory=lambda: np.array([]))
    wall_time: Array = field(default_factory=lambda: np.array([]))
    columns: dict[str, Array] = field(default_factory=dict)
    cameras: dict[str, CameraFrames] = field(default_factory=dict)

    def column(self, name: str) -> Array:
        return self.columns[name]

    def tlog_packets(self) -> Iterator[tuple[float, bytes]]:
        """`(t_s, packet)` of each MAVLink packet in the recording's tlog, on the session
        clock of its rows: a replayed tlog's by the replay's own clock (each recording of
        a joined log on its own, as its rows), a recorded session's by its receive time
        less the rows' wall-clock offset. Only packets that decode to a known message of
        a replayed tlog are given (those the replay read)."""
        if self.tlog is None:
            return
        if self.from_tlog:
            t0: int | None = None
            for t_us, _, _, packet, _ in _on_session_clock(self.tlog):
                t0 = t_us if t0 is None else t0
                yield (t_us - t0) * 1e-6, packet
            return
        t_s, wall = self.t_s, self.wall_time
        if not t_s.size:
            t_s, wall, _ = read_columns(self.telemetry_csv, (), self.source)
        d = wall - t_s
        d = d[np.isfinite(d)]
        offset = float(np.median(d)) if d.size else 0.0
        for t, packet in TlogReader(self.tlog):
            yield t - offset, packet

    def vehicle_texts(self) -> list[tuple[float | None, str]]:
        """The vehicle's STATUSTEXTs (session time, text), from the session's messages.csv
        or replayed from its tlog; [] when the recording has neither."""
        return vehicle_texts(self.messages_csv) if self.messages_csv is not None else []

    def frame_bytes(self, camera: str, k: int) -> bytes:
        """The recorded JPEG bytes of frame `k` (an index into `cameras[camera]`)."""
        return frame_pack.frame_bytes(self.folder, self.cameras[camera].index, k)


def parse_meta(raw: bytes) -> dict:
    """A session.json's content; {} when it is not a JSON object (metadata is a nicety:
    a broken file must not stop reading the flight)."""
    try:
        meta = json.loads(raw)
    except (ValueError, UnicodeDecodeError):
        return {}
    return meta if isinstance(meta, dict) else {}


def _meta_dir(folder: Path) -> dict:
    for name in META_FILES:
        f = folder / name
        if f.is_file():
            return parse_meta(f.read_bytes())
    return {}


def _session_of_tlog(path: Path) -> Path | None:
    """The session folder whose own tlog `path` is, if it is one."""
    folder = path.parent
    if path.name == layout.MAVLINK_TLOG and (folder / layout.SESSION_JSON).is_file():
        return folder
    return None


def recording_meta(path: str | Path) -> dict:
    """Only the metadata (session.json) of a recording, {} if it has none: what a caller
    needs before it opens recordings, without reading telemetry or unpacking a zip."""
    p = Path(path)
    if p.is_dir():
        return _meta_dir(p)
    if p.suffix.lower() == ".zip":
        try:
            with zipfile.ZipFile(p) as zf:
                names = [n for n in zf.namelist() if Path(n).name in META_FILES]
                if not names:
                    return {}
                # The shallowest, as `_unzip` picks the session's folder.
                return parse_meta(zf.read(min(names, key=lambda n: (n.count("/"), n))))
        except (zipfile.BadZipFile, OSError) as exc:
            raise RecordingError(f"'{p}' is not a readable zip: {exc}") from None
    if not p.exists():
        raise RecordingError(f"'{p}' does not exist; give a session folder, zip or .tlog.")
    session = _session_of_tlog(p) if p.suffix.lower() == ".tlog" else None
    return _meta_dir(session) if session is not None else {}


@contextlib.contextmanager
def open_recording(
    path: str | Path, columns: Sequence[str] = (), frames: bool = True
) -> Iterator[Recording]:
    """Open a session folder, session zip or bare tlog for the duration of a `with`.

    `columns`: telemetry.csv columns read as floats into `Recording.columns` (with
    `t_s` and `wall_time`); `frames`: list the cameras' frames (and unpack them from a
    zip)."""
    p = Path(path)
    if not p.exists():
        raise RecordingError(f"'{p}' does not exist; give a session folder, zip or .tlog.")
    with tempfile.TemporaryDirectory(prefix="fpv-recording-") as tmp:
        if p.is_dir():
            rec = _session(p, str(p), Path(tmp), frames)
        elif p.suffix.lower() == ".zip":
            rec = _session(_unzip(p, Path(tmp) / "zip", frames), str(p), Path(tmp), frames)
        elif p.suffix.lower() == ".tlog":
            session = _session_of_tlog(p)
            meta = _meta_dir(session) if session is not None else {}
            name = str(meta.get("id") or p.stem)
            rec = _replayed(p, str(p), name, meta, Path(tmp))
        else:
            raise RecordingError(f"'{p}' is not a session folder, .zip or .tlog.")
        if columns:
            rec.t_s, rec.wall_time, rec.columns = read_columns(rec.telemetry_csv, columns, str(p))
        yield rec


def _session(folder: Path, source: str, tmp: Path, frames: bool) -> Recording:
    meta = _meta_dir(folder)
    name = str(meta.get("id") or (Path(source).stem if source.endswith(".zip") else folder.name))
    named = folder / layout.MAVLINK_TLOG
    tlog = named if named.is_file() else next(iter(sorted(folder.glob("*.tlog"))), None)
    csv_path = folder / layout.TELEMETRY_CSV
    if csv_path.is_file():
        rec = Recording(name, source, folder, csv_path, tlog, meta, from_tlog=False)
        messages = folder / layout.MESSAGES_CSV
        rec.messages_csv = messages if messages.is_file() else None
    elif tlog is not None:
        rec = _replayed(tlog, source, name, meta, tmp)
        rec.folder = folder
    else:
        raise RecordingError(f"'{source}' has neither {layout.TELEMETRY_CSV} nor a .tlog.")
    if frames:
        for cam in meta.get("cameras") or layout.CAMERAS:
            found = _camera_frames(folder, str(cam))
            if found is not None:
                rec.cameras[str(cam)] = found
    return rec


def _unzip(zip_path: Path, into: Path, frames: bool) -> Path:
    """Unpack a session zip (without its camera frames unless `frames`); returns the
    folder that holds its session files."""
    into.mkdir()
    try:
        with zipfile.ZipFile(zip_path) as zf:
            names = zf.namelist()
            for name in names:
                if not (into / name).resolve().is_relative_to(into.resolve()):
                    raise RecordingError(f"'{zip_path}' has an unsafe member path '{name}'.")
            if not frames:  # the session's own files: telemetry, tlog, metadata
                names = [
                    n
                    for n in names
                    if Path(n).name in (layout.TELEMETRY_CSV, layout.MESSAGES_CSV, *META_FILES)
                    or n.lower().endswith(".tlog")
                ]
            zf.extractall(into, names)
    except (zipfile.BadZipFile, OSError) as exc:
        raise RecordingError(f"'{zip_path}' is not a readable zip: {exc}") from None
    marks = sorted(
        (f.parent for f in into.rglob("*") if f.name in (layout.TELEMETRY_CSV, *META_FILES)),
        key=lambda d: len(d.parts),
    )
    if marks:
        return marks[0]
    tlogs = sorted(into.rglob("*.tlog"), key=lambda f: len(f.parts))
    if tlogs:
        return tlogs[0].parent
    raise RecordingError(f"'{zip_path}' holds no session (no {layout.TELEMETRY_CSV} or .tlog).")


def _camera_frames(folder: Path, camera: str) -> CameraFrames | None:
    """The camera's frames whose bytes are on disk (None: no frames.csv, or none)."""
    index = frame_pack.read_index(folder, camera)
    if index is None:
        return None
    index = index.where(frame_pack.on_disk(folder, index) & np.isfinite(index.t_s))
    if not len(index):
        return None
    return CameraFrames(camera, index, int(index.width[0]), int(index.height[0]))


# ---------------------------------------------------------------- a tlog replayed


def _row_hz(meta: dict) -> float:
    quality = meta.get("quality")
    rate = quality.get("telemetry_rate_hz") if isinstance(quality, dict) else None
    return float(rate) if isinstance(rate, (int, float)) and rate > 0 else DEFAULT_ROW_HZ


def _replayed(tlog: Path, source: str, name: str, meta: dict, tmp: Path) -> Recording:
    csv_path, messages = tmp / layout.TELEMETRY_CSV, tmp / layout.MESSAGES_CSV
    replay_tlog(tlog, csv_path, _row_hz(meta), source, messages)
    return Recording(name, source, tmp, csv_path, tlog, meta, True, messages)


def replay_tlog(
    tlog: Path,
    out: Path,
    rate_hz: float,
    source: str | None = None,
    messages_out: Path | None = None,
) -> int:
    """Write the telemetry.csv a recorder would have written from the link that received
    `tlog`, and to `messages_out` its messages.csv (what the vehicle said, written at each
    row as the recorder writes it; every message of the log, as in a recording that
    started with the log): each record's packet decoded as the link decodes a whole
    packet (`FastDecoder`; a tlog record is one packet, so no bytes carry over), tracked by a
    `StateTracker` on the log's clock, a row every `1 / rate_hz` s with the state that
    held at that instant (the packets stamped at or before it). Returns the rows written.

    A record that decodes to no packet (junk, a bad checksum) does not move the clock.
    Across a silence longer than `FILL_GAP_S` the grid restarts at the next packet
    rather than filling the silence with rows of the same state (a log paused for hours,
    or a station clock set forward by its time service).

    A log that holds several recordings (its clock steps back: `TlogReader.segments`)
    is read as the link replays it: each recording by a new tracker that knows nothing
    yet, on its own clock. Their rows follow one another: a later recording's session
    time (`t_s`, and the state's times) continues `FILL_GAP_S` after the one before,
    while `wall_time` stays the log's own; so no flight is interleaved with another.
    """
    source = source or str(tlog)
    period_us = 1e6 / rate_hz
    formatter: RowFormatter | None = None
    tracker = StateTracker()
    rows = n = 0
    grid0 = last = 0  # µs on the session clock: the grid's start, the newest packet
    shift = 0  # µs: session clock - the log's clock, in this recording
    said: Any = None  # messages.csv's writer
    seen = 0  # the tracker's message count at the last row

    def row(f: TextIO, formatter: RowFormatter, at_us: int) -> None:
        nonlocal rows, n, seen
        sample = Sample(at_us * 1e-6, (at_us - shift) * 1e-6, tracker.state, ())
        f.write(formatter.line(sample))
        new, seen = message_rows(sample, seen, formatter.t0_mono)
        said.writerows(new)
        rows += 1
        n += 1

    def rows_until(f: TextIO, formatter: RowFormatter, end_us: int, inclusive: bool) -> None:
        while (at := grid0 + round(n * period_us)) < end_us or (inclusive and at == end_us):
            row(f, formatter, at)

    try:
        with (
            open(out, "w", newline="", buffering=1 << 16) as f,
            open(messages_out or os.devnull, "w", newline="") as m,
        ):
            said = csv.writer(m)
            said.writerow(layout.MESSAGE_COLUMNS)
            for t_us, t_log, msg, _, new in _on_session_clock(tlog):
                if formatter is None:
                    formatter = RowFormatter((), t_log * 1e-6)
                    f.write(formatter.header_line())
                    grid0 = last = t_us
                elif new:  # the next recording: a new tracker
                    rows_until(f, formatter, last, inclusive=True)
                    tracker, seen = StateTracker(), 0
                    shift = t_us - t_log
                    grid0, n = t_us, 0
                if t_us - last > FILL_GAP_S * 1e6:
                    rows_until(f, formatter, last, inclusive=True)
                    grid0, n = t_us, 0
                rows_until(f, formatter, t_us, inclusive=False)
                tracker.update(msg, t_us * 1e-6)
                last = t_us
            if formatter is not None:  # the instants up to the last packet
                rows_until(f, formatter, last, inclusive=True)
    except OSError as exc:
        raise RecordingError(f"'{source}' cannot be read: {exc}") from None
    if not rows:
        raise RecordingError(f"'{source}' holds no MAVLink packet.")
    return rows


def _on_session_clock(tlog: Path) -> Iterator[tuple[int, int, Any, bytes, bool]]:
    """`(t_us, t_log_us, message, packet, new_recording)` for each record of `tlog` that
    decodes to a known message (`replay_tlog`'s clock): `t_us` on the replay's session
    clock before its zero is taken off (the first packet's `t_log_us`), each recording
    of a joined log `FILL_GAP_S` after the one before; `new_recording` on the first
    packet of each recording after the first."""
    decoder = FastDecoder()
    last: int | None = None  # µs on the session clock: the newest packet
    shift = 0  # µs: session clock - the log's clock, in this recording
    for segment, records in TlogReader(tlog).segments():
        started = False
        for t, packet in records:
            try:
                msg = decoder.decode(bytearray(packet))
            except MAVError:
                continue
            if msg is None or isinstance(msg, MAVLink_unknown):
                continue
            t_log = round(t * 1e6)
            new = False
            if last is not None and not started and segment > 0:
                new = True
                shift = last + round(FILL_GAP_S * 1e6) - t_log
            started = True
            last = t_log + shift
            yield last, t_log, msg, packet, new


# ---------------------------------------------------------------- columns


def read_columns(
    path: Path, names: Sequence[str], source: str
) -> tuple[Array, Array, dict[str, Array]]:
    """`t_s`, `wall_time` and the named columns of a telemetry.csv as floats (NaN where
    empty or absent), read block by block: memory holds those columns, never the whole
    file."""
    wanted = ("t_s", "wall_time", *names)
    parts: dict[str, list[Array]] = {n: [] for n in wanted}
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
                for n in wanted:
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
