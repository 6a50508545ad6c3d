"""A camera's recorded frames, for every reader: the index from its frames.csv, and one
frame's bytes, in either session format.

Format 2 (`layout.FORMAT_VERSION`): `<camera>/frames.mjpeg` (the frame pack) holds every
frame's JPEG bytes back to back in capture order, a raw MJPEG stream; frames.csv gives
each frame's `offset` (first byte in the pack) and `bytes` (length). The recorder appends
one batch of JPEGs to the pack, then their rows to frames.csv: a row never names bytes
that are not in the pack, and after a kill only the last batch can have bytes without
rows (`companion.recording.ondisk` cuts them off). Format 1: a file per frame,
`<camera>/00000042.jpg`, and no `offset` column. A frame's name (`front/00000042.jpg`,
`layout.frame_relpath`) is the same in both; only where its bytes are differs.

Which format a camera is in is read from its frames.csv header (an `offset` column), so
a reader needs neither session.json nor a listing of the folder. The index holds numpy
arrays (a 20-minute flight is 36,000 frames a camera, not 36,000 dicts) and is extended
from where it stopped reading while frames.csv grows (a session being recorded).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fpv_station.companion.recording import layout


class FrameNotOnDisk(LookupError):
    """A frame frames.csv lists whose bytes are not (or no longer) on disk."""


@dataclass(frozen=True)
class FrameIndex:
    """One camera's frames.csv as arrays, in file order (capture order), bad rows skipped."""

    camera: str
    packed: bool  # format 2: the bytes are in the camera's frames.mjpeg at `offset`
    seq: NDArray[np.int64]
    t_s: NDArray[np.float64]  # capture time, session clock
    width: NDArray[np.int32]  # pixels (0: unknown)
    height: NDArray[np.int32]
    offset: NDArray[np.int64]  # first byte in frames.mjpeg (format 1: 0)
    size: NDArray[np.int64]  # JPEG bytes
    # Where reading stopped: frames.csv's identity, its size then and the end of its
    # last complete line (a row still being written is read next time).
    csv_id: tuple[int, int]  # (st_dev, st_ino): a rewritten file (recovery) is re-read
    csv_size: int
    csv_mtime_ns: int
    csv_end: int
    header: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.seq.size)

    def find(self, seq: int) -> int | None:
        """The index of frame `seq`, or None when frames.csv does not list it."""
        k = int(np.searchsorted(self.seq, seq))
        if k < self.seq.size and self.seq[k] == seq:
            return k
        # Not in order (a hand-made or damaged file): look it up the slow way.
        if self.seq.size > 1 and not bool(np.all(self.seq[1:] > self.seq[:-1])):
            hits = np.flatnonzero(self.seq == seq)
            return int(hits[0]) if hits.size else None
        return None

    def where(self, keep: NDArray[np.bool_]) -> FrameIndex:
        """Only the frames where `keep` is True (for reading; not to be extended)."""
        return dataclasses.replace(
            self,
            **{n: getattr(self, n)[keep] for n in _ARRAYS},
        )

    def name(self, k: int) -> str:
        """Frame `k`'s name relative to the session folder (`front/00000042.jpg`)."""
        return layout.frame_relpath(self.camera, int(self.seq[k]))


def read_index(folder: Path, camera: str, previous: FrameIndex | None = None) -> FrameIndex | None:
    """The index of `camera` in the session `folder`, None when it has no frames.csv.

    With `previous` (an index of the same file), only what was appended since is read;
    `previous` itself is returned when nothing was."""
    return read_index_file(folder / layout.frames_csv_relpath(camera), camera, previous)


def read_index_file(
    path: Path, camera: str, previous: FrameIndex | None = None
) -> FrameIndex | None:
    """`read_index` for a frames.csv at `path` (a path the caller has checked)."""
    try:
        f = open(path, "rb")  # noqa: SIM115 (closed below)
    except FileNotFoundError:
        return None
    with f:
        st = os.fstat(f.fileno())
        csv_id = (st.st_dev, st.st_ino)
        if (
            previous is not None
            and previous.header
            and previous.csv_id == csv_id
            and previous.csv_end <= st.st_size  # recovery cuts only a partial last line
        ):
            if (previous.csv_size, previous.csv_mtime_ns) == (st.st_size, st.st_mtime_ns):
                return previous
            f.seek(previous.csv_end)
            return _extend(previous, f.read(st.st_size - previous.csv_end), st)
        data = f.read(st.st_size)
    first = data.find(b"\n") + 1
    if first == 0:  # not even a whole header yet: read it all again next time
        return _empty(camera, (), csv_id, 0)
    header = tuple(next(csv.reader([data[:first].decode("utf-8", "replace")]), []))
    return _extend(_empty(camera, header, csv_id, first), data[first:], st)


def _empty(camera: str, header: tuple[str, ...], csv_id: tuple[int, int], end: int) -> FrameIndex:
    i64, f64, i32 = np.zeros(0, np.int64), np.zeros(0, np.float64), np.zeros(0, np.int32)
    packed = "offset" in header
    return FrameIndex(camera, packed, i64, f64, i32, i32, i64, i64, csv_id, -1, -1, end, header)


_ARRAYS = ("seq", "t_s", "width", "height", "offset", "size")
_NUMERIC = ("seq", "t_s", "width", "height", "offset", "bytes")  # _ARRAYS' frames.csv columns


def _extend(index: FrameIndex, data: bytes, st: os.stat_result) -> FrameIndex:
    """`index` with the complete rows of `data`, read from its `csv_end` of the file
    whose state is now `st`."""
    whole = data[: data.rfind(b"\n") + 1]
    new = _parse_rows(whole, index.header, index.packed)
    grown: dict[str, Any] = {  # field name -> its longer array
        name: np.concatenate([getattr(index, name), new[column].astype(getattr(index, name).dtype)])
        for name, column in zip(_ARRAYS, _NUMERIC, strict=True)
        if new["seq"].size
    }
    return dataclasses.replace(
        index,
        **grown,
        csv_size=st.st_size,
        csv_mtime_ns=st.st_mtime_ns,
        csv_end=index.csv_end + len(whole),
    )


def _parse_rows(whole: bytes, header: tuple[str, ...], packed: bool) -> dict[str, NDArray]:
    """The numeric columns of complete frames.csv lines (`_NUMERIC` names), bad rows left
    out. numpy's C parser first (a 20-minute flight's 36,000 rows in a third of the
    csv module's time, which a Pi pays when a replay opens); the csv module when a row
    is damaged or a field empty (a row recovery added without pixels)."""
    cols = {n: header.index(n) for n in _NUMERIC if n in header}
    if not whole or not {"seq", "bytes"} <= cols.keys() or (packed and "offset" not in cols):
        return {n: np.zeros(0) for n in _NUMERIC}
    names = [n for n in _NUMERIC if n in cols]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # an empty line is a damaged row here
            table = np.loadtxt(
                io.BytesIO(whole),
                delimiter=",",
                usecols=[cols[n] for n in names],
                dtype=np.float64,
                ndmin=2,
                encoding="utf-8",
            )
    except (ValueError, UserWarning):
        return _parse_rows_slowly(whole, cols, packed)
    out = {n: table[:, i] for i, n in enumerate(names)}
    rows = table.shape[0]
    out.setdefault("t_s", np.full(rows, np.nan))
    for n in ("width", "height", "offset"):
        out.setdefault(n, np.zeros(rows))
    if not packed:
        out["offset"] = np.zeros(rows)
    keep = (out["offset"] >= 0) & (out["bytes"] >= 0)
    return {n: v[keep] for n, v in out.items()}


def _parse_rows_slowly(whole: bytes, cols: dict[str, int], packed: bool) -> dict[str, NDArray]:
    """`_parse_rows` row by row, skipping what does not parse."""
    parsed: dict[str, list[float]] = {n: [] for n in _NUMERIC}
    lists = [parsed[n] for n in _NUMERIC]
    for row in csv.reader(whole.decode("utf-8", "replace").splitlines()):
        try:
            values = (
                int(row[cols["seq"]]),
                _number(row, cols.get("t_s"), float("nan")),
                int(_number(row, cols.get("width"), 0)),
                int(_number(row, cols.get("height"), 0)),
                int(row[cols["offset"]]) if packed else 0,
                int(row[cols["bytes"]]),
            )
        except (IndexError, ValueError):
            continue  # a damaged row: not a frame anyone can find
        if values[4] < 0 or values[5] < 0:
            continue
        for out, v in zip(lists, values, strict=True):
            out.append(v)
    return {n: np.asarray(v, np.float64) for n, v in parsed.items()}


def _number(row: list[str], k: int | None, default: float) -> float:
    """Field `k` of `row` as a number; `default` when the column is absent or empty."""
    if k is None or k >= len(row) or row[k] == "":
        return default
    return float(row[k])


def on_disk(folder: Path, index: FrameIndex) -> NDArray[np.bool_]:
    """Which of the listed frames have their bytes on disk: inside the pack (format 2), or
    an existing file (format 1)."""
    if index.packed:
        try:
            pack_size = os.stat(folder / layout.frames_pack_relpath(index.camera)).st_size
        except FileNotFoundError:
            pack_size = 0
        return index.offset + index.size <= pack_size
    return np.array([(folder / index.name(k)).is_file() for k in range(len(index))], bool)


def frame_bytes(folder: Path, index: FrameIndex, k: int) -> bytes:
    """The JPEG bytes of frame `k` of `index`; FrameNotOnDisk when they are not there."""
    if index.packed:
        pack = folder / layout.frames_pack_relpath(index.camera)
        return read_packed(pack, int(index.offset[k]), int(index.size[k]))
    try:
        return (folder / index.name(k)).read_bytes()
    except (FileNotFoundError, NotADirectoryError):
        raise FrameNotOnDisk(f"{index.name(k)} is not on disk") from None


def read_packed(pack: Path, offset: int, size: int) -> bytes:
    """`size` bytes at `offset` of a frame pack; FrameNotOnDisk when the pack is shorter
    (a session recovered since its index was read)."""
    try:
        fd = os.open(pack, os.O_RDONLY | os.O_CLOEXEC)
    except (FileNotFoundError, NotADirectoryError):
        raise FrameNotOnDisk(f"{pack} is not on disk") from None
    try:
        data = os.pread(fd, size, offset)
    finally:
        os.close(fd)
    if len(data) != size:
        raise FrameNotOnDisk(f"{pack} ends before byte {offset + size}")
    return data
