"""Read a few columns of a large, plain CSV fast, as byte strings.

An hour of telemetry at 50 Hz is 180,000 rows of ~100 columns (~50 MB); analysis needs
about ten columns and, after keeping one row per GPS message, a fifth of the rows.
`np.loadtxt` tokenizes every field (about 1.2 s for such a file on the Pi-class test
machine); here one vectorized pass finds every separator, and fields are then cut out
only for the columns and rows asked for. A file with quotes, or rows of the wrong width
(a power cut mid-row), goes through the csv module instead, keeping the whole rows.
"""

from __future__ import annotations

import csv
import io

import numpy as np
from numpy.typing import NDArray

Bytes = NDArray[np.bytes_]


class CsvColumns:
    """The body of a CSV (no header) with `width` fields per row."""

    def __init__(self, body: bytes, width: int) -> None:
        if not body.endswith(b"\n"):
            body = body[: body.rfind(b"\n") + 1]  # a file still being written: drop the cut row
        body = body.replace(b"\r\n", b"\n") if b"\r" in body else body
        self.width = width
        self._buf = np.frombuffer(body, np.uint8)
        self._table: Bytes | None = None
        seps = np.flatnonzero((self._buf == ord(",")) | (self._buf == ord("\n")))
        ends = seps.reshape(-1, width) if seps.size % width == 0 and b'"' not in body else None
        # Every row must end in a newline exactly at its last separator.
        if ends is not None and (
            not ends.size or bool(np.all(self._buf[ends[:, -1]] == ord("\n")))
        ):
            self._ends = ends  # (rows, width) positions of each field's terminator
            self.rows = int(ends.shape[0])
        else:
            rows = [
                r
                for r in csv.reader(io.StringIO(body.decode("utf-8", "replace")))
                if len(r) == width
            ]
            self._table = np.array(rows, dtype=np.bytes_).reshape(len(rows), width)
            self.rows = len(rows)

    def column(self, k: int, rows: NDArray[np.intp] | None = None) -> Bytes:
        """Column `k` as byte strings (b"" for an empty cell), for `rows` or all rows."""
        if self._table is not None:
            col = self._table[:, k]
            return col if rows is None else col[rows]
        # A field starts after the previous field's terminator (the row's first field
        # after the previous row's newline).
        e = self._ends[:, k] if rows is None else self._ends[rows, k]
        if k > 0:
            s = (self._ends[:, k - 1] if rows is None else self._ends[rows, k - 1]) + 1
        else:
            prev = np.concatenate([[-1], self._ends[:-1, -1]])
            s = (prev if rows is None else prev[rows]) + 1
        if s.size == 0:
            return np.array([], dtype="S1")
        length = e - s
        w = max(int(length.max()), 1)
        offsets = np.arange(w, dtype=np.int64)
        idx = s[:, None] + offsets
        chars = self._buf[np.minimum(idx, self._buf.size - 1)]
        chars = np.where(offsets < length[:, None], chars, 0).astype(np.uint8)
        return chars.view(f"S{w}").ravel()  # numpy strips the trailing NULs


def to_float(values: Bytes) -> NDArray[np.float64]:
    """Byte strings to float; empty, None, null become NaN, True/False become 1/0."""
    v = np.char.strip(values)
    bad = (v == b"") | (v == b"None") | (v == b"null")
    v = np.where(bad, b"nan", v)
    v = np.where(v == b"True", b"1", np.where(v == b"False", b"0", v))
    try:
        return v.astype(np.float64)
    except ValueError as exc:
        raise ValueError(f"a numeric column holds text: {exc}") from None


def to_bool(values: Bytes) -> NDArray[np.bool_]:
    v = np.char.lower(np.char.strip(values))
    return (v == b"true") | (v == b"1") | (v == b"1.0")
