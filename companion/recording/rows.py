"""Turning one telemetry sample into one telemetry.csv row (the columns of `layout`).

A sample is cheap to take (references to immutable snapshots and a few floats); the
writer thread formats it when it writes the batch.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from operator import attrgetter
from typing import Any

from fpv_station.companion.recording import layout
from fpv_station.companion.vehicle_state import VehicleState


@dataclass(frozen=True, slots=True)
class FrameRef:
    """The newest recorded frame of a camera at a row's instant."""

    seq: int
    t_mono: float
    t_wall: float


@dataclass(frozen=True, slots=True)
class Sample:
    t_mono: float
    t_wall: float
    state: VehicleState | None
    frames: tuple[FrameRef | None, ...]  # one per camera, in the session's camera order


@dataclass(frozen=True, slots=True)
class _GroupColumns:
    """One state group's columns: a getter of all their fields (a tuple, in column order),
    which of them take an element of a tuple field, and which are monotonic times."""

    get: Callable[[Any], tuple[Any, ...]]
    indexed: tuple[tuple[int, int], ...]  # (column, element)
    monos: tuple[int, ...]

    @classmethod
    def of(cls, cols: list[tuple[str, int | None]]) -> _GroupColumns:
        fields = [field for field, _ in cols]
        get = attrgetter(*fields)
        return cls(
            get=get if len(fields) > 1 else lambda obj: (get(obj),),
            indexed=tuple((pos, index) for pos, (_, index) in enumerate(cols) if index is not None),
            monos=tuple(
                pos
                for pos, (field, index) in enumerate(cols)
                if index is None and (field == "t_mono" or field.endswith("_mono"))
            ),
        )


_EOL = "\r\n"  # the csv module's excel dialect ends its rows so


class _CsvText:
    """Cells as the `csv` module writes them into a row (its quoting and number text),
    without the line's end."""

    def __init__(self) -> None:
        self._buf = io.StringIO()
        self._writer = csv.writer(self._buf, lineterminator="")

    def __call__(self, cells: Sequence[Any]) -> str:
        buf = self._buf
        buf.seek(0)
        buf.truncate()
        self._writer.writerow(cells)
        return buf.getvalue()


class RowFormatter:
    """Turns samples into telemetry.csv lines (csv's excel dialect, CRLF); `header` is
    exactly `layout.telemetry_columns(cameras)`, and `header_line` its line."""

    def __init__(self, cameras: tuple[str, ...], t0_mono: float) -> None:
        self.cameras = cameras
        self.t0_mono = t0_mono
        self.header = layout.telemetry_columns(cameras)
        # Per state group: its getter and its columns' (built once from the dataclass
        # fields: a new VehicleState field becomes a column without touching this module).
        groups: dict[str, list[tuple[str, int | None]]] = {}
        for group, field, index in layout.state_fields():
            groups.setdefault(group, []).append((field, index))
        self._groups = [(attrgetter(g), _GroupColumns.of(cols)) for g, cols in groups.items()]
        # The link shares unchanged groups between snapshots (frozen dataclasses), and
        # most groups change at 1-20 Hz while rows go at up to 100 Hz: a group's text
        # (formatting numbers as text is most of a row's cost: 126 columns, most of them
        # floats) is reused while the group is the same object.
        self._text_cache: list[tuple[Any, str]] = [(None, "")] * len(self._groups)
        self._csv_text = _CsvText()
        self._empty_state = VehicleState()

    def _group_cells(self, obj: Any, cols: _GroupColumns) -> list[Any]:
        values = list(cols.get(obj))  # every field at once (one C call)
        for pos, index in cols.indexed:  # an element of a tuple field (pwm_us[3])
            value = values[pos]
            values[pos] = value[index] if index < len(value) else None
        t0 = self.t0_mono
        for pos in cols.monos:  # station monotonic -> session clock
            if values[pos] is not None:
                values[pos] = round(values[pos] - t0, 6)
        return ["" if v is None else 1 if v is True else 0 if v is False else v for v in values]

    def header_line(self) -> str:
        """The file's first line: the column names, written as the rows are."""
        return self._csv_text(self.header) + _EOL

    def line(self, s: Sample) -> str:
        """The telemetry.csv line of `s`, as `csv.writer` writes its cells."""
        text = self._csv_text
        parts = [text(self._times(s))]
        state = s.state if s.state is not None else self._empty_state
        cache = self._text_cache
        for i, (get_group, cols) in enumerate(self._groups):
            obj = get_group(state)
            cached_obj, group_text = cache[i]
            if obj is not cached_obj:  # identity: the cache holds obj, so ids never recycle
                group_text = text(self._group_cells(obj, cols))
                cache[i] = (obj, group_text)
            parts.append(group_text)
        frames = self._frame_cells(s)
        if frames:  # no camera, no frame columns (and no empty text between commas)
            parts.append(text(frames))
        return ",".join(parts) + _EOL

    def _times(self, s: Sample) -> list[Any]:
        return [round(s.t_mono - self.t0_mono, 6), round(s.t_wall, 6)]

    def _frame_cells(self, s: Sample) -> list[Any]:
        out: list[Any] = []
        for cam, ref in zip(self.cameras, s.frames):
            if ref is None:
                out.extend(("", "", "", ""))
            else:
                out.extend(
                    (
                        ref.seq,
                        layout.frame_relpath(cam, ref.seq),
                        round(ref.t_wall, 6),
                        round(s.t_mono - ref.t_mono, 6),
                    )
                )
        return out


def message_rows(sample: Sample, seen: int | None, t0_mono: float) -> tuple[list[tuple], int]:
    """The messages.csv rows (`layout.MESSAGE_COLUMNS`) of what the vehicle said since the
    state's message count was `seen` (None: nothing yet: messages from before the
    session started are not the session's), and the count now. A burst beyond what the
    state keeps is one station row that says how many were not kept."""
    log_ = sample.state.messages if sample.state is not None else None
    if log_ is None:
        return [], seen if seen is not None else 0
    if seen is None or log_.count <= seen:
        return [], log_.count
    new = log_.recent[-(log_.count - seen) :]
    rows: list[tuple] = []
    if log_.count - seen > len(new):
        lost = log_.count - seen - len(new)
        rows.append(
            (
                round(new[0].t_mono - t0_mono, 6),
                "",
                6,
                "station",
                f"{lost} older messages not kept in the burst (see mavlink.tlog)",
                "",
                "",
            )
        )
    offset = sample.t_wall - sample.t_mono  # station monotonic -> Unix time
    for m in new:
        rows.append(
            (
                round(m.t_mono - t0_mono, 6),
                round(m.t_mono + offset, 6),
                m.severity,
                m.kind,
                m.text,
                m.command or "",
                m.result or "",
            )
        )
    return rows, log_.count
