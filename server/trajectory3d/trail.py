"""The flown path as a list of chunks, so that the scene appends instead of resending.

Each chunk holds up to `chunk_segments` segments and becomes one scene handle. Only the
newest (open) chunk changes while the vehicle flies; a full chunk is frozen and a new one
starts at its last point, so the line stays continuous across chunks. The cost of one
update is therefore bounded by the chunk size, whatever the length of the flight.

Gaps: a sample flagged `starts_run` (after a lost fix or a silence longer than the gap
threshold) is not joined to the point before it, so a dropout is drawn as a gap, never as
a straight jump. Samples are kept geodetic, so that a new origin (the arming point)
re-projects the whole path exactly. They are projected to ENU when first drawn, all the
new ones of a chunk in one vectorized call: a panel nobody watches projects nothing.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

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


@dataclass(slots=True)
class TrailChunk:
    """Consecutive samples; point i is joined to point i-1 unless `starts_run[i]`."""

    id: int
    geo: list[tuple[float, float, float]] = field(default_factory=list)
    speed_mps: list[float] = field(default_factory=list)
    starts_run: list[bool] = field(default_factory=list)
    # ENU about `origin` of the first len(enu_m) points of `geo` (`project` does the rest);
    # a chunk built from ENU alone (the replay's) has no geo and is always complete.
    enu_m: list[NDArray[np.float64]] = field(default_factory=list)
    origin: Origin | None = None

    @property
    def n_segments(self) -> int:
        return sum(1 for s in self.starts_run[1:] if not s)

    def project(self) -> None:
        """Bring `enu_m` up to `geo`: every point not projected yet, in one call."""
        done = len(self.enu_m)
        if done < len(self.geo) and self.origin is not None:
            g = np.asarray(self.geo[done:])
            self.enu_m.extend(geodetic_to_enu(g[:, 0], g[:, 1], g[:, 2], *self.origin))

    def segments(self) -> tuple[NDArray[np.float32], NDArray[np.float64], NDArray[np.float64]]:
        """(N, 2, 3) segment end points in ENU, (N, 2) heights, (N, 2) speeds."""
        self.project()
        if len(self.enu_m) < 2:
            empty = np.zeros((0, 2))
            return np.zeros((0, 2, 3), np.float32), empty, empty
        p = np.asarray(self.enu_m)
        v = np.asarray(self.speed_mps)
        joined = ~np.asarray(self.starts_run[1:], bool)
        idx = np.nonzero(joined)[0] + 1
        pts = np.stack([p[idx - 1], p[idx]], axis=1)
        return (
            pts.astype(np.float32),
            pts[:, :, 2],
            np.stack([v[idx - 1], v[idx]], axis=1),
        )


class Trail:
    """Samples in chunks, with gap detection and an origin that may move."""

    def __init__(self, chunk_segments: int = 50, gap_s: float = 1.0, max_points: int = 200_000):
        if chunk_segments < 1:
            raise ValueError("chunk_segments must be at least 1.")
        self.chunk_segments = chunk_segments
        self.gap_s = gap_s
        self.max_points = max_points
        self.origin: Origin | None = None
        self.chunks: list[TrailChunk] = []
        self.n_points = 0
        self._ids = itertools.count()
        self._last_t_s: float | None = None
        self._gap_pending = True  # the first point starts a run

    def clear(self) -> list[TrailChunk]:
        """Forget the path (the origin stays); returns the chunks that were dropped."""
        dropped, self.chunks = self.chunks, []
        self.n_points = 0
        self._last_t_s = None
        self._gap_pending = True
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
        for chunk in self.chunks:  # re-projected when next drawn
            chunk.origin = origin
            chunk.enu_m = []
        return True

    def append(self, s: TrailSample) -> tuple[TrailChunk, list[TrailChunk]]:
        """Add one sample. Returns the chunk that changed (possibly a new one) and the old
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
        chunk = self.chunks[-1] if self.chunks else None
        if chunk is None or chunk.n_segments >= self.chunk_segments:
            new = TrailChunk(next(self._ids), origin=self.origin)
            if chunk is not None and chunk.geo and not starts_run:
                # Repeat the last point so the line is continuous across chunks.
                new.geo.append(chunk.geo[-1])
                new.speed_mps.append(chunk.speed_mps[-1])
                new.starts_run.append(True)
            self.chunks.append(new)
            chunk = new
        chunk.geo.append((s.lat_deg, s.lon_deg, s.alt_m))
        chunk.speed_mps.append(s.speed_mps)
        chunk.starts_run.append(starts_run)
        self.n_points += 1
        dropped = []
        while self.n_points > self.max_points and len(self.chunks) > 1:
            old = self.chunks.pop(0)
            self.n_points -= len(old.geo)
            dropped.append(old)
        return chunk, dropped

    @property
    def last_enu_m(self) -> NDArray[np.float64] | None:
        if not self.chunks:
            return None
        chunk = self.chunks[-1]
        chunk.project()
        return chunk.enu_m[-1] if chunk.enu_m else None
