"""Sample times from the vehicle's own clock (`time_usec`, `time_boot_ms`), placed on the
session (receive) clock.

A log stamps each packet when it arrived. A radio that fades and comes back delivers the
packets it buffered as one burst with one receive time, so receive times make speeds out
of nothing (a burst after a 4.3 s gap: 63 m/s where the GPS said 28 m/s). The vehicle
stamps each message when it was made, so we keep the vehicle's spacing and put it on the
receive clock by the shortest delay (receive minus vehicle time) from the sample to
`WINDOW_S` later (in a stretch's last `WINDOW_S`: over that last stretch of time): the
packet that came straight through. So a sample is never placed after it arrived, a burst
takes its place from the packets around it, and the placement follows a vehicle clock
that runs at another rate than the station's (the twin's simulated clock on a loaded
machine: seconds a minute), keeping the times on the session clock of the rows and
frames. Nor is a sample placed before the previous sample arrived (the receive time
before its own): a loaded station reads a stretch of packets late, each a few tenths of a
second, and the packet that came straight through after it would otherwise put the whole
stretch that much before its rows; bounded so, at any instant the sample that analysis
measures is the row's or the one after it, and a burst after a fade still spreads over
the silence before it. A reboot (the vehicle's clock goes back) or a switch of time base
(PX4 moving GPS_RAW_INT from boot time to GPS time) starts a new stretch with delays of
its own. Samples without a vehicle time (0 or NaN) keep their receive time.

When the session measured the vehicle's clock with TIMESYNC (session.json
`clock.vehicle_boot`, `companion.timesync`), a stretch on that clock is placed by that
mapping instead (never after a sample arrived, nor before the previous one arrived): one
line for the whole session, the same that puts the onboard log on the session clock
(`analysis.onboard_log`). A stretch the mapping does not fit (another time base, a
reboot) keeps the shortest delay.

Views of a session draw at the receive times (the rows'); these times are for measuring.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import ValidationError

from fpv_station.companion.timesync import VehicleClock

Array = NDArray[np.float64]

# The two clocks tick at about one rate; their spacings differing by more than this is a
# new vehicle clock, not a delay (a radio buffers seconds, not minutes).
NEW_CLOCK_S = 60.0
# How far ahead a sample looks for a packet that came straight through: longer than a
# burst's spread after a fade, short against a clock's drift (the shift is at most the
# drift over this window, and only where the vehicle's clock runs faster).
WINDOW_S = 5.0


# A stretch the measured mapping fits: its samples arrive after they were made (within
# the mapping's error) and, in the middle, no later than a radio buffers (WINDOW_S).
FIT_EARLY_S = 0.25


def vehicle_boot_clock(meta: dict) -> VehicleClock | None:
    """The session's measured vehicle clock (session.json `clock.vehicle_boot`, on the
    session clock); None when it has none or it was not measured."""
    raw = (meta.get("clock") or {}).get("vehicle_boot")
    if not isinstance(raw, dict):
        return None
    try:
        boot = VehicleClock.model_validate(raw)
    except ValidationError:
        return None
    return boot if boot.method == "timesync" and boot.offset_s is not None else None


def on_vehicle_clock(
    receive_s: ArrayLike, vehicle_s: ArrayLike, boot: VehicleClock | None = None
) -> Array:
    """Times (s, on the receive clock) spaced as the vehicle's clock says; `receive_s`
    in the order received; `boot`: the measured mapping of the vehicle's boot clock onto
    the receive clock, used for the stretches it fits."""
    r = np.asarray(receive_s, dtype=np.float64)
    v = np.asarray(vehicle_s, dtype=np.float64)
    out = r.copy()
    ok = np.flatnonzero(np.isfinite(v) & (v > 0) & np.isfinite(r))
    if ok.size == 0:
        return out
    rv, vv = r[ok], v[ok]
    step_v, step_r = np.diff(vv), np.diff(rv)
    new = (step_v < 0) | (np.abs(step_v - step_r) > NEW_CLOCK_S)
    # Each sample's window: itself up to WINDOW_S later, within its stretch; in a
    # stretch's last WINDOW_S, its last WINDOW_S (a burst at the end has nothing after).
    cuts = np.flatnonzero(new) + 1
    first = np.concatenate([[0], cuts])
    after = np.concatenate([cuts, [rv.size]])
    stretch = np.concatenate([[0], np.cumsum(new)])
    r_sorted = np.maximum.accumulate(rv)
    end = np.minimum(np.searchsorted(r_sorted, rv + WINDOW_S, side="right"), after[stretch])
    tail = r_sorted[after[stretch] - 1] - WINDOW_S
    start = np.searchsorted(r_sorted, np.minimum(rv, tail), side="left")
    start = np.minimum(np.maximum(start, first[stretch]), np.arange(rv.size))
    out[ok] = np.minimum(vv + _range_min(rv - vv, start, end), rv)  # exactly, not to a rounding
    if boot is not None:
        mapped = boot.station_s(vv)
        late = rv - mapped
        for k in range(first.size):
            sl = slice(first[k], after[k])
            if -FIT_EARLY_S <= np.median(late[sl]) <= WINDOW_S:
                out[ok[sl]] = np.minimum(mapped[sl], rv[sl])
    before = np.searchsorted(r_sorted, rv, side="left") - 1  # the last arrival before it
    out[ok] = np.maximum(out[ok], np.where(before >= 0, r_sorted[np.maximum(before, 0)], -np.inf))
    return out


def _range_min(a: Array, start: NDArray[np.intp], end: NDArray[np.intp]) -> Array:
    """min(a[start[i]:end[i]]) for every i (each range non-empty), by a sparse table:
    level k holds the minimum of the 2**k values from each index."""
    levels = [a]
    while 2 ** len(levels) <= a.size:
        prev, half = levels[-1], 2 ** (len(levels) - 1)
        levels.append(np.minimum(prev[:-half], prev[half:]))
    length = end - start
    k = np.floor(np.log2(length)).astype(np.intp)
    out = np.empty(a.size)
    for level in np.unique(k):
        m = k == level
        table = levels[level]
        out[m] = np.minimum(table[start[m]], table[end[m] - 2**level])
    return out
