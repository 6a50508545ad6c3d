"""What a session folder really holds, counted from its files, for a session whose writer
was cut off: killed (kill -9, power loss) or stopped by a failed write (a full disk).

The writer's own counters say what it handed to the OS; after a kill or a failed flush
some of that never reached the disk (the buffered tail of each CSV, the tlog's last
record, the frames being written). `take_census` counts what is there and makes each
camera's frames.csv list exactly the complete frames on disk.

Format 2 (a frame pack, `<camera>/frames.mjpeg`; `companion.recording.frame_pack`): the
writer appends a batch of JPEGs to the pack, then their frames.csv rows, so a kill can
leave pack bytes without rows (the batch being written) and a partial last row, never
a row without its bytes unless the disk lost them (a power cut):

- a row is kept when its bytes [offset, offset + bytes) lie inside the pack, after the
  previous kept frame, start with SOI and end with EOI; any other row is removed;
- the pack is truncated after the last kept frame: what follows (the cut batch: nothing
  names those frames, not even a telemetry row, which the writer writes after them) is
  counted in bytes (`pack_tail_removed`).

Format 1 (a file per frame, `<camera>/00000042.jpg`):

- a complete JPEG (SOI ... EOI) that frames.csv does not list (its row was still in the
  buffer) gets its row back: size from the file, pixels from its SOF header, capture
  time from the telemetry row that named it, else from the file's time (written a few ms
  after capture);
- a row naming a file that is missing or of another size is removed;
- a cut JPEG (no EOI: the one being written at the kill or when the disk filled) is
  deleted: it is not a frame (the capture path refuses such a buffer too), and on a full
  disk its blocks are what lets frames.csv and session.json be finished.

`apply_census` puts the counts into a session's metadata (`quality` and `recovery`).
A file that is missing counts as empty; one that is there but cannot be read (EIO on a
damaged card, EMFILE) raises OSError: counting it as empty would report its data lost.
docs/SESSION_FORMAT.md ("Durability") describes the outcome for readers.
"""

from __future__ import annotations

import csv
import io
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

from fpv_station.companion.cameras.jpeg import EOI, SOI, jpeg_size
from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import Recovery, SessionMeta
from fpv_station.core.mavlink.tlog_records import TlogReader

log = logging.getLogger(__name__)


@dataclass
class FramesOnDisk:
    """One camera after reconciling: `rows` is what frames.csv lists (in seq order)."""

    rows: list[tuple[str, ...]] = field(default_factory=list)
    added: int = 0  # complete JPEGs frames.csv did not list
    rows_removed: int = 0  # rows naming a missing file or one of another size
    partial_removed: list[str] = field(default_factory=list)  # cut JPEGs deleted
    unlisted: int = 0  # complete JPEGs frames.csv still does not list (it could not be written)
    pack_tail_removed: int = 0  # bytes cut off the end of frames.mjpeg (format 2)

    @property
    def complete(self) -> int:
        """Complete JPEGs on disk."""
        return len(self.rows)

    def seq(self, k: int) -> int:
        return int(self.rows[k][0])

    def achieved_fps(self) -> float | None:
        try:
            span = float(self.rows[-1][2]) - float(self.rows[0][2])
        except (IndexError, ValueError):
            return None
        return round((len(self.rows) - 1) / span, 3) if len(self.rows) > 1 and span > 0 else None


@dataclass
class Census:
    telemetry_rows: int = 0
    telemetry_cut_line: bool = False
    last_row_t_s: float | None = None
    last_row_wall: float | None = None
    tlog_packets: int = 0
    tlog_cut_record: bool = False
    frames: dict[str, FramesOnDisk] = field(default_factory=dict)


def take_census(folder: Path, cameras: list[str], start_wall: float) -> Census:
    """Count the session's rows, packets and frames on disk, reconciling each frames.csv."""
    telemetry = _scan_telemetry(folder / layout.TELEMETRY_CSV)
    lines = telemetry.lines
    census = Census(telemetry_rows=telemetry.rows, telemetry_cut_line=telemetry.cut)
    if len(lines) >= 2:
        last = _row_dict(lines[0], lines[-1])
        census.last_row_t_s = _float(last.get("t_s"))
        census.last_row_wall = _float(last.get("wall_time"))
    tlog = TlogReader(folder / layout.MAVLINK_TLOG)
    try:
        census.tlog_packets = sum(1 for _ in tlog)
    except FileNotFoundError:
        pass
    census.tlog_cut_record = tlog.truncated > 0
    for cam in cameras:
        census.frames[cam] = reconcile_frames(folder, cam, lines, start_wall)
    return census


def reconcile_frames(
    folder: Path, camera: str, telemetry_lines: list[str], start_wall: float
) -> FramesOnDisk:
    """Make `<camera>/frames.csv` list exactly the complete frames on disk: in its frame
    pack (format 2), else its JPEG files (format 1); OSError when what is there cannot be
    read."""
    if os.path.lexists(folder / layout.frames_pack_relpath(camera)):
        return _reconcile_pack(folder, camera)
    return _reconcile_files(folder, camera, telemetry_lines, start_wall)


def _reconcile_pack(folder: Path, camera: str) -> FramesOnDisk:
    """Format 2: keep the rows whose bytes are a whole JPEG in the pack, in order; cut the
    pack after the last of them."""
    out = FramesOnDisk()
    csv_path = folder / layout.frames_csv_relpath(camera)
    old = _complete_lines(csv_path)
    header = next(csv.reader(old.lines[:1]), None) or list(layout.FRAME_COLUMNS)
    try:
        i_seq, i_size, i_off = (header.index(n) for n in ("seq", "bytes", "offset"))
    except ValueError:  # a damaged header: the writer's columns
        i_seq, i_size, i_off = (layout.FRAME_COLUMNS.index(n) for n in ("seq", "bytes", "offset"))
    kept: list[tuple[str, ...]] = []
    listed: set[int] = set()
    end = 0  # the end of the last kept frame
    with open(folder / layout.frames_pack_relpath(camera), "r+b") as pack:
        fd = pack.fileno()
        pack_size = os.fstat(fd).st_size
        for row in csv.reader(old.lines[1:]):
            try:
                seq, size, offset = int(row[i_seq]), int(row[i_size]), int(row[i_off])
            except (IndexError, ValueError):
                out.rows_removed += 1
                continue
            if (
                seq in listed
                or size < len(SOI) + len(EOI)
                or offset < end
                or offset + size > pack_size
                or os.pread(fd, len(SOI), offset) != SOI
                or os.pread(fd, len(EOI), offset + size - len(EOI)) != EOI
            ):
                out.rows_removed += 1
                continue
            kept.append(tuple(row))
            listed.add(seq)
            end = offset + size
        out.rows = kept
        out.pack_tail_removed = pack_size - end
        if out.pack_tail_removed:
            # First: on a full disk the freed blocks are what lets frames.csv be rewritten.
            pack.truncate(end)
            os.fsync(fd)
    try:
        if out.rows_removed or not old.lines:
            _replace_rows(csv_path, kept, layout.FRAME_COLUMNS)
        elif old.cut:
            _append_rows(csv_path, old.size, [])
    except OSError as exc:
        log.warning(
            "cannot rewrite %s: %s; it still lists %d removed rows", csv_path, exc, out.rows_removed
        )
    return out


def _reconcile_files(
    folder: Path, camera: str, telemetry_lines: list[str], start_wall: float
) -> FramesOnDisk:
    """Format 1: make frames.csv list exactly the complete JPEG files in the folder."""
    out = FramesOnDisk()
    cam_dir = folder / camera
    csv_path = folder / layout.frames_csv_relpath(camera)
    sizes: dict[int, tuple[str, int]] = {}  # seq -> (file name, bytes)
    try:
        with os.scandir(cam_dir) as it:
            for entry in it:
                m = layout.FRAME_NAME_RE.match(entry.name)
                if m and entry.is_file(follow_symlinks=False):
                    sizes[int(m.group(1))] = (entry.name, entry.stat(follow_symlinks=False).st_size)
    except FileNotFoundError:
        return out
    old = _complete_lines(csv_path)
    old_rows = list(csv.reader(old.lines[1:]))
    kept: list[tuple[str, ...]] = []
    listed: set[int] = set()
    for row in old_rows:
        try:
            seq, size = int(row[0]), int(row[6])
        except (IndexError, ValueError):
            out.rows_removed += 1
            continue
        if seq in sizes and sizes[seq][1] == size and seq not in listed:
            kept.append(tuple(row))
            listed.add(seq)
        else:
            out.rows_removed += 1
    unlisted = sorted(s for s in sizes if s not in listed)
    times = _frame_times(camera, telemetry_lines, set(unlisted)) if unlisted else {}
    added: list[tuple[str, ...]] = []
    for seq in unlisted:
        name, _ = sizes[seq]
        path = cam_dir / name
        try:
            data = path.read_bytes()
        except FileNotFoundError:  # removed since the folder was listed
            continue
        if not (data.startswith(SOI) and data.endswith(EOI)):
            try:
                path.unlink()
                out.partial_removed.append(f"{camera}/{name}")
            except OSError as exc:
                log.warning("cannot remove the cut frame %s: %s", path, exc)
            continue
        width, height = jpeg_size(data) or ("", "")
        if seq in times:
            t_s, t_wall = times[seq]
        else:  # no flushed row named it: the file's time, a few ms after its capture
            t_wall = os.stat(path).st_mtime
            t_s = t_wall - start_wall
        rel = layout.frame_relpath(camera, seq)
        cells = (seq, rel, round(t_s, 6), round(t_wall, 6), width, height, len(data))
        added.append(tuple(str(v) for v in cells))
    out.added = len(added)
    out.rows = sorted(kept + added, key=lambda r: int(r[0]))
    if not added and not out.rows_removed and not old.cut:
        return out  # frames.csv already lists exactly the complete frames
    appending = out.rows_removed == 0 and out.rows[: len(kept)] == kept
    try:
        if appending and old.lines:
            _append_rows(csv_path, old.size, out.rows[len(kept) :])
        else:
            _replace_rows(csv_path, out.rows, layout.FRAME_COLUMNS_V1)
    except OSError as exc:
        out.unlisted = len(added)
        log.warning("cannot rewrite %s: %s; %d frames stay unlisted", csv_path, exc, len(added))
    return out


def apply_census(meta: SessionMeta, census: Census, recovered_utc: str) -> None:
    """Set `meta`'s counts to what is on disk. What the writer counted but the disk does
    not hold (a buffer lost with a failed write) becomes dropped, so that captured =
    written + dropped still holds."""
    q = meta.quality
    q.telemetry_rows_dropped += max(0, q.telemetry_rows - census.telemetry_rows)
    q.telemetry_rows = census.telemetry_rows
    if census.last_row_t_s and census.telemetry_rows > 1:
        q.telemetry_achieved_hz = round((census.telemetry_rows - 1) / census.last_row_t_s, 3)
    q.tlog_packets_dropped += max(0, q.tlog_packets - census.tlog_packets)
    q.tlog_packets = census.tlog_packets
    for cam, fd in census.frames.items():
        cq = q.cameras.get(cam)
        if cq is None:
            continue
        cq.frames_dropped_queue += max(0, cq.frames_written - fd.complete)
        cq.frames_written = fd.complete
        cq.first_seq = fd.seq(0) if fd.rows else None
        cq.last_seq = fd.seq(-1) if fd.rows else None
        cq.achieved_fps = fd.achieved_fps()
        seen = fd.seq(-1) - fd.seq(0) + 1 if fd.rows else 0
        cq.frames_captured = max(cq.frames_captured, seen, cq.frames_written)
        cq.frames_missed = max(0, cq.frames_captured - cq.frames_written - cq.frames_dropped_queue)
        cq.frames_dropped = cq.frames_missed + cq.frames_dropped_queue
        cq.frames_captured = cq.frames_written + cq.frames_dropped
    if census.last_row_wall is not None:
        meta.end_wall = round(census.last_row_wall, 6)
        offset = meta.clock.offset_s if meta.clock is not None else 0.0  # the session's UTC
        meta.end_utc = layout.utc_label(census.last_row_wall + offset)
        meta.duration_s = round(census.last_row_wall - meta.start_wall, 3)
    meta.recovery = Recovery(
        utc=recovered_utc,
        telemetry_cut_line=census.telemetry_cut_line,
        tlog_cut_record=census.tlog_cut_record,
        frames_added={c: f.added for c, f in census.frames.items()},
        frame_rows_removed={c: f.rows_removed for c, f in census.frames.items()},
        partial_frames_removed=[p for f in census.frames.values() for p in f.partial_removed],
        frames_unlisted={c: f.unlisted for c, f in census.frames.items()},
        pack_tail_removed={c: f.pack_tail_removed for c, f in census.frames.items()},
    )


def _csv_bytes(rows: list[tuple[str, ...]], header: tuple[str, ...] = ()) -> bytes:
    buf = io.StringIO()
    w = csv.writer(buf)  # the writer's dialect, as the recorder wrote the file
    if header:
        w.writerow(header)
    w.writerows(rows)
    return buf.getvalue().encode()


def _append_rows(path: Path, keep: int, rows: list[tuple[str, ...]]) -> None:
    """Cut a partial last line (keep `keep` bytes) and append `rows`: no new file, so it
    needs only the rows' bytes on a full disk."""
    with open(path, "r+b") as f:
        f.truncate(keep)
        f.seek(keep)
        f.write(_csv_bytes(rows))
        f.flush()
        os.fsync(f.fileno())


def _replace_rows(path: Path, rows: list[tuple[str, ...]], header: tuple[str, ...]) -> None:
    """Write `header` and `rows` to a temp file and rename it over `path`."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(_csv_bytes(rows, header))
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _frame_times(camera: str, lines: list[str], wanted: set[int]) -> dict[int, tuple[float, float]]:
    """(t_s, t_wall) of frames named by telemetry rows (`lines`: the header, then the
    newest rows): the row's time minus its skew. Reads from the end: unlisted frames are
    the newest."""
    if len(lines) < 2 or not wanted:
        return {}
    header = next(csv.reader([lines[0]]))
    try:
        i_t, i_seq = header.index("t_s"), header.index(f"{camera}.seq")
        i_wall, i_skew = header.index(f"{camera}.t_wall"), header.index(f"{camera}.skew_s")
    except ValueError:
        return {}
    low = min(wanted)
    found: dict[int, tuple[float, float]] = {}
    for line in reversed(lines[1:]):
        try:
            row = next(csv.reader([line]))
            seq = int(row[i_seq])
            t = (float(row[i_t]) - float(row[i_skew]), float(row[i_wall]))
        except (ValueError, IndexError, StopIteration):
            continue
        if seq < low:
            break
        if seq in wanted:
            found.setdefault(seq, t)
    return found


TELEMETRY_TAIL_BYTES = 1 << 20  # the newest rows kept in memory: ~10 s at 100 Hz


@dataclass
class _TelemetryScan:
    rows: int  # complete rows (lines after the header)
    cut: bool  # a partial last line was left out
    lines: list[str]  # the header, then the newest complete rows (TELEMETRY_TAIL_BYTES)


def _scan_telemetry(path: Path) -> _TelemetryScan:
    """Count telemetry.csv's rows in chunks, keeping only its header and newest rows: an
    hour's file is hundreds of MB, more than a Pi should read into memory at once."""
    try:
        f = open(path, "rb")  # noqa: SIM115 (closed below, after the tail is read)
    except FileNotFoundError:
        return _TelemetryScan(0, False, [])
    with f:
        header = f.readline()
        if not header.endswith(b"\n"):
            return _TelemetryScan(0, bool(header), [])
        rows, pos, last_nl = 0, len(header), len(header)
        while chunk := f.read(1 << 20):
            rows += chunk.count(b"\n")
            nl = chunk.rfind(b"\n")
            if nl >= 0:
                last_nl = pos + nl + 1
            pos += len(chunk)
        start = max(len(header), last_nl - TELEMETRY_TAIL_BYTES)
        f.seek(start)
        tail = f.read(last_nl - start)
    if start > len(header):  # began mid-line: that line is not whole
        tail = tail[tail.find(b"\n") + 1 :]
    text = (header + tail).decode("utf-8", errors="replace")
    return _TelemetryScan(rows, pos > last_nl, text.splitlines())


@dataclass
class _Lines:
    """The complete lines of a CSV whose writer was cut, and what was cut."""

    lines: list[str]
    cut: bool  # a partial last line was left out
    size: int  # bytes through the last newline


def _complete_lines(path: Path) -> _Lines:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return _Lines([], False, 0)
    end = data.rfind(b"\n") + 1
    text = data[:end].decode("utf-8", errors="replace")
    return _Lines(text.splitlines(), len(data) > end, end)


def _row_dict(header_line: str, line: str) -> dict[str, str]:
    return dict(zip(next(csv.reader([header_line])), next(csv.reader([line])), strict=False))


def _float(v: str | None) -> float | None:
    try:
        return float(v) if v not in (None, "") else None
    except ValueError:
        return None
