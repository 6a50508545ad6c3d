"""Split a track into flights: armed periods in which the vehicle took off.

A session, and even more a tlog downloaded from an autopilot, often holds several
sorties: arm, take off, land, disarm, walk the vehicle back, arm again. It can also hold
an arm-disarm on the ground (a motor test) and a tail recorded after the last disarm.
Each flight is one armed period (a run of armed samples) that contains a take-off: a
climb of more than `takeoff_height_m` above the height at arming that lasts at least
`min_airborne_s`. Armed periods without one are not flights; samples outside armed
periods belong to no flight.

Heights are taken per armed period relative to its first sample with a height: the pilot's
altitude is zeroed at arming anyway, while GPS altitude drifts by metres between sorties,
and a vehicle walked back up a slope starts its next flight from another level.

Pure vectorized numpy over whole arrays; the times are those of the `t_s` you pass (the
vehicle's clock where the track has one). Indices are inclusive and index the arrays
given, so `track.select(flight.samples)` is that flight's track.

Usage:
    for f in track_flights(track):
        print(f.number, f.takeoff_s, f.landing_s)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fpv_station.analysis.track import Track

Array = NDArray[np.float64]

TAKEOFF_HEIGHT_M = 0.5  # as analysis.tasks.TaskParams.airborne_height_m
MIN_AIRBORNE_S = 1.0  # as TaskParams.min_airborne_s: GPS altitude wander on the pad is no flight


@dataclass(frozen=True)
class Flight:
    """One flight of a track. Indices are inclusive sample indices into the arrays split."""

    number: int  # 1-based, in time order (what `--flight N` counts)
    arm: int  # first armed sample
    disarm: int  # last armed sample (the last sample of the track if it never disarmed)
    takeoff: int  # first airborne sample
    landing: int  # last airborne sample
    arm_s: float
    disarm_s: float
    takeoff_s: float
    landing_s: float

    @property
    def samples(self) -> slice:
        """The armed period, for indexing arrays or `Track.select`."""
        return slice(self.arm, self.disarm + 1)

    @property
    def airborne_s(self) -> float:
        """Take-off to landing."""
        return self.landing_s - self.takeoff_s


def split_flights(
    t_s: ArrayLike,
    armed: ArrayLike,
    height_m: ArrayLike,
    takeoff_height_m: float = TAKEOFF_HEIGHT_M,
    min_airborne_s: float = MIN_AIRBORNE_S,
) -> list[Flight]:
    """The flights in time-ordered samples `t_s`, `armed` (bool), `height_m` (NaN where
    unknown). A track with no armed sample at all (a log without the autopilot's
    HEARTBEAT) is taken as one armed period, so that height alone decides."""
    t = np.asarray(t_s, dtype=np.float64)
    h = np.asarray(height_m, dtype=np.float64)
    on = np.asarray(armed, dtype=bool)
    if not (t.shape == h.shape == on.shape) or t.ndim != 1:
        raise ValueError("t_s, armed and height_m must be 1-D arrays of one length")
    if t.size == 0:
        return []
    if not on.any():
        on = np.ones(t.size, dtype=bool)

    arm, disarm = _runs(on)
    period = np.cumsum(np.diff(np.concatenate([[0], on.astype(np.int8)])) == 1) - 1
    # Ground level of each period: the height of its first sample that has one.
    known = np.flatnonzero(on & np.isfinite(h))
    ids, first = np.unique(period[known], return_index=True)
    ground = np.full(arm.size, np.nan)
    ground[ids] = h[known[first]]

    above = np.zeros(t.size, dtype=bool)
    above[on] = h[on] - ground[period[on]] > takeoff_height_m  # NaN compares False
    up, down = _runs(above)  # airborne runs never cross a period: `above` implies armed
    long_enough = (t[down] - t[up]) >= min_airborne_s
    up, down = up[long_enough], down[long_enough]
    if up.size == 0:
        return []
    # Per period, the first kept run's start and the last kept run's end (runs are in
    # time order, so np.unique's first index and the next group's index minus one).
    flown, first_run, count = np.unique(period[up], return_index=True, return_counts=True)
    takeoff, landing = up[first_run], down[first_run + count - 1]
    a, d = arm[flown], disarm[flown]
    return [
        Flight(
            number=k + 1,
            arm=int(a[k]),
            disarm=int(d[k]),
            takeoff=int(takeoff[k]),
            landing=int(landing[k]),
            arm_s=float(t[a[k]]),
            disarm_s=float(t[d[k]]),
            takeoff_s=float(t[takeoff[k]]),
            landing_s=float(t[landing[k]]),
        )
        for k in range(flown.size)
    ]


def track_flights(
    track: Track,
    takeoff_height_m: float = TAKEOFF_HEIGHT_M,
    min_airborne_s: float = MIN_AIRBORNE_S,
) -> list[Flight]:
    """The flights of a loaded track, on its `t_s` clock. Height: the pilot's altitude
    where the track has it, else GPS altitude (as analysis decides events, see
    `analysis.flight_frame`); one or the other for the whole track, as their zeros differ."""
    rel = track.relative_alt_m
    height = rel if np.isfinite(rel).any() else track.alt_m
    return split_flights(track.t_s, track.armed, height, takeoff_height_m, min_airborne_s)


def _runs(mask: NDArray[np.bool_]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """First and last (inclusive) indices of each run of True."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
