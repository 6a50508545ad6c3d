"""The flown path as a list of chunks, so that the scene appends instead of resending.

Each chunk holds up to `chunk_segments` segments and becomes one scene handle. Only the
newest (open) chunk changes while the vehicle flies; a full chunk is frozen and a new one
starts at its last point, so the line stays continuous across chunks. The cost of one
update is therefore bounded by the chunk size, whatever the length of the flight.

Gaps: a sample flagged `starts_run` (after a lost fix or a silence longer than the gap
threshold) is not joined to the point before it, so a dropout is drawn as a gap, never as
a straight jump. A sample less than `min_step_m` from the trail's last point is held, not
added: a parked vehicle adds no points however long the station runs, and its jitter
draws nothing. A held sample still counts as heard for the gap threshold (a vehicle that
sat still and flies again continues its run), and the newest one held becomes a point
when its run ends, so the line ends where the vehicle last was. Samples are kept
geodetic, so that a new origin (the arming point) re-projects the whole path exactly.
They are projected to ENU when first drawn, all the new ones of a chunk in one vectorized
call: a panel nobody watches projects nothing.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fpv_station.core.geodesy import geodetic_to_enu

Origin = tuple[float, float, float]  # lat_deg, lon_deg, alt_m (MSL)


@dataclass(frozen=True, slots=True)
class TrailSample:
    t_s: float  # station monotonic time of the fix
    lat_deg: float
    lon_deg: float
    alt_m: float  # MSL
    speed_mps: float  # NaN when unknown


class TrailChunk:
    """Consecutive samples; point i is joined to point i-1 unless `starts_run[i]`.

    The samples live in a few numpy arrays per chunk, grown by doubling, not in Python
    objects per point: a moving vehicle gives the live trail `update_hz` points a second
    (up to `max_points`), and the Pi's memory pays for each."""

    __slots__ = ("id", "origin", "n", "n_segments", "_geo", "_speed", "_starts", "_enu", "_done")

    def __init__(self, id: int, origin: Origin | None = None, capacity: int = 16) -> None:
        self.id = id
        self.origin = origin  # of the ENU points; a chunk without geo (the replay's) has none
        self.n = 0  # points
        self.n_segments = 0  # points joined to the one before
        capacity = max(capacity, 2)
        self._geo = np.empty((capacity, 3))
        self._speed = np.empty(capacity)
        self._starts = np.empty(capacity, bool)
        self._enu = np.empty((capacity, 3))
        self._done = 0  # points projected to ENU about `origin` (`project` does the rest)

    @classmethod
    def from_enu(
        cls, id: int, enu_m: NDArray[np.float64], speed_mps: NDArray, starts_run: NDArray
    ) -> TrailChunk:
        """A chunk built from ENU alone (the replay's): no geo, always projected."""
        n = len(enu_m)
        chunk = cls(id, capacity=n)
        chunk._enu[:n] = enu_m
        chunk._speed[:n] = speed_mps
        chunk._starts[:n] = starts_run
        chunk.n = chunk._done = n
        chunk.n_segments = int(n - np.count_nonzero(chunk._starts[1:n]) - 1) if n else 0
        return chunk

    def add(self, geo: tuple[float, float, float], speed_mps: float, starts_run: bool) -> None:
        if self.n == len(self._geo):
            self._grow()
        i = self.n
        self._geo[i] = geo
        self._speed[i] = speed_mps
        self._starts[i] = starts_run
        self.n += 1
        if i > 0 and not starts_run:
            self.n_segments += 1

    def _grow(self) -> None:
        size = 2 * len(self._geo)
        for name in ("_geo", "_speed", "_starts", "_enu"):
            old = getattr(self, name)
            new = np.empty((size, *old.shape[1:]), old.dtype)
            new[: self.n] = old[: self.n]
            setattr(self, name, new)

    def last(self) -> tuple[tuple[float, float, float], float]:
        """The newest point: its (lat, lon, alt) and speed."""
        lat, lon, alt = self._geo[self.n - 1].tolist()
        return (lat, lon, alt), float(self._speed[self.n - 1])

    def reproject(self, origin: Origin) -> None:
        """Points about a new origin: projected again when next drawn."""
        self.origin = origin
        self._done = 0

    def project(self) -> None:
        """Bring the ENU points up to the samples: every point not projected yet, in one call."""
        done, n = self._done, self.n
        if done < n and self.origin is not None:
            g = self._geo[done:n]
            self._enu[done:n] = geodetic_to_enu(g[:, 0], g[:, 1], g[:, 2], *self.origin)
            self._done = n

    @property
    def last_enu_m(self) -> NDArray[np.float64] | None:
        self.project()
        return self._enu[self._done - 1].copy() if self._done else None

    def segments(self) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float64]]:
        """(N, 2, 3) segment end points in ENU, (N, 2) heights, (N, 2) speeds."""
        self.project()
        n = self._done
        if n < 2:
            empty = np.zeros((0, 2))
            return np.zeros((0, 2, 3), np.float32), empty, empty
        p, v = self._enu[:n], self._speed[:n]
        idx = np.nonzero(~self._starts[1:n])[0] + 1
        pts = np.stack([p[idx - 1], p[idx]], axis=1)
        return (
            pts.astype(np.float32),
            pts[:, :, 2],
            np.stack([v[idx - 1], v[idx]], axis=1),
        )


class Trail:
    """Samples in chunks, with gap detection and an origin that may move."""

    def __init__(
        self,
        chunk_segments: int = 50,
        gap_s: float = 1.0,
        max_points: int = 200_000,
        min_step_m: float = 0.0,
    ):
        if chunk_segments < 1:
            raise ValueError("chunk_segments must be at least 1.")
        self.chunk_segments = chunk_segments
        self.gap_s = gap_s
        self.max_points = max_points
        self.min_step_m = min_step_m
        self.origin: Origin | None = None
        self.chunks: list[TrailChunk] = []
        self.n_points = 0
        self._ids = itertools.count()
        self._last_t_s: float | None = None  # of the newest sample, added or held
        self._gap_pending = True  # the first point starts a run
        self.held: TrailSample | None = None  # the newest sample, when not added

    def clear(self) -> list[TrailChunk]:
        """Forget the path (the origin stays); returns the chunks that were dropped."""
        dropped, self.chunks = self.chunks, []
        self.n_points = 0
        self._last_t_s = None
        self._gap_pending = True
        self.held = None
        return dropped

    def mark_gap(self) -> None:
        """The fix is lost: the next sample starts a new run."""
        self._gap_pending = True

    def set_origin(self, origin: Origin) -> bool:
        """Move the ENU origin; re-projects every point. True if it moved."""
        # Plain floats, not np.allclose: this runs on every update of the panel.
        if self.origin is not None and all(
            abs(a - b) <= 1e-9 for a, b in zip(origin, self.origin, strict=True)
        ):
            return False
        self.origin = origin
        for chunk in self.chunks:
            chunk.reproject(origin)
        return True

    def append(self, s: TrailSample) -> tuple[list[TrailChunk], list[TrailChunk]]:
        """Add one sample. Returns the chunks that changed (none when the sample is held,
        two when a held sample closes a run and the new one opens a chunk) and the old
        chunks dropped to stay under `max_points`."""
        if self.origin is None:
            self.origin = (s.lat_deg, s.lon_deg, s.alt_m)
        starts_run = (
            self._gap_pending
            or self._last_t_s is None
            or s.t_s - self._last_t_s > self.gap_s
            or s.t_s < self._last_t_s
        )
        self._gap_pending = False
        self._last_t_s = s.t_s
        changed: list[TrailChunk] = []
        if not starts_run and self.chunks and self._near_last_point(s):
            self.held = s
            return changed, []
        if starts_run and self.held is not None:
            changed.append(self._add(self.held, starts_run=False))  # the run's true end
        self.held = None
        chunk = self._add(s, starts_run)
        if not changed or changed[-1] is not chunk:
            changed.append(chunk)
        dropped = []
        while self.n_points > self.max_points and len(self.chunks) > 1:
            old = self.chunks.pop(0)
            self.n_points -= old.n
            dropped.append(old)
        return [c for c in changed if c not in dropped], dropped

    def _near_last_point(self, s: TrailSample) -> bool:
        if self.min_step_m <= 0:
            return False
        geo, _ = self.chunks[-1].last()
        step = geodetic_to_enu(s.lat_deg, s.lon_deg, s.alt_m, *geo)
        return float(np.linalg.norm(step)) < self.min_step_m

    def _add(self, s: TrailSample, starts_run: bool) -> TrailChunk:
        chunk = self.chunks[-1] if self.chunks else None
        if chunk is None or chunk.n_segments >= self.chunk_segments:
            # Room for a chunk's segments and the point it starts from.
            assert self.origin is not None
            new = TrailChunk(next(self._ids), self.origin, capacity=self.chunk_segments + 1)
            if chunk is not None and chunk.n and not starts_run:
                # Repeat the last point so the line is continuous across chunks.
                new.add(*chunk.last(), starts_run=True)
            self.chunks.append(new)
            chunk = new
        chunk.add((s.lat_deg, s.lon_deg, s.alt_m), s.speed_mps, starts_run)
        self.n_points += 1
        return chunk

    @property
    def last_enu_m(self) -> NDArray[np.float64] | None:
        return self.chunks[-1].last_enu_m if self.chunks else None
