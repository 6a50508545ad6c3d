"""Turning one telemetry sample into one telemetry.csv row (the columns of `layout`).

A sample is cheap to take (references to immutable snapshots and a few floats); the
writer thread formats it when it writes the batch.
"""

from __future__ import annotations

from dataclasses import dataclass
from operator import attrgetter
from typing import Any

from companion.recording import layout
from companion.vehicle_state import VehicleState


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


def _cell(value: Any) -> Any:
    if value is None:
        return ""
    if value is True:
        return 1
    if value is False:
        return 0
    return value


class RowFormatter:
    """Flattens samples into rows; `header` is exactly `layout.telemetry_columns(cameras)`."""

    def __init__(self, cameras: tuple[str, ...], t0_mono: float) -> None:
        self.cameras = cameras
        self.t0_mono = t0_mono
        self.header = layout.telemetry_columns(cameras)
        # Per state group: its attribute name and one (field getter, tuple index, is a
        # monotonic time) per column, built once from the dataclass fields (generic: a new
        # VehicleState field becomes a column without touching this module).
        groups: dict[str, list[tuple[Any, int | None, bool]]] = {}
        for group, field, index in layout.state_fields():
            is_mono = field == "t_mono" or field.endswith("_mono")
            groups.setdefault(group, []).append((attrgetter(field), index, is_mono))
        self._groups = [(attrgetter(g), cols) for g, cols in groups.items()]
        # The link shares unchanged groups between snapshots (frozen dataclasses), so the
        # cells of a group are reused while it is the same object: most groups change at
        # 1-20 Hz while rows go at up to 100 Hz.
        self._cache: list[tuple[Any, list[Any]]] = [(None, [])] * len(self._groups)
        self._empty_state = VehicleState()

    def _group_cells(self, obj: Any, cols: list[tuple[Any, int | None, bool]]) -> list[Any]:
        t0 = self.t0_mono
        cells = []
        for getter, index, is_mono in cols:
            value = getter(obj)
            if index is not None:
                value = value[index] if index < len(value) else None
            elif is_mono and value is not None:
                value = round(value - t0, 6)  # station monotonic -> session clock
            cells.append(_cell(value))
        return cells

    def row(self, s: Sample) -> list[Any]:
        t0 = self.t0_mono
        out: list[Any] = [round(s.t_mono - t0, 6), round(s.t_wall, 6)]
        state = s.state if s.state is not None else self._empty_state
        cache = self._cache
        for i, (get_group, cols) in enumerate(self._groups):
            obj = get_group(state)
            cached_obj, cells = cache[i]
            if obj is not cached_obj:  # identity: the cache holds obj, so ids never recycle
                cells = self._group_cells(obj, cols)
                cache[i] = (obj, cells)
            out.extend(cells)
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
