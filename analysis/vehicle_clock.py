"""Sample times from the vehicle's own clock (`time_usec`, `time_boot_ms`), placed on the
receive clock.

A log stamps each packet when it arrived. A radio that fades and comes back delivers the
packets it buffered as one burst with one receive time, so receive times make speeds out
of nothing (a burst after a 4.3 s gap: 63 m/s where the GPS said 28 m/s). The vehicle
stamps each message when it was made. We keep the vehicle's spacing and put it on the
receive clock by the typical (median) delay, per stretch of one vehicle clock: a reboot (its clock goes back) or a switch of time base
(PX4 moving GPS_RAW_INT from boot time to GPS time) starts a new stretch. Samples without
a vehicle time (0 or NaN) keep their receive time.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

# The two clocks tick at one rate; their spacings differing by more than this is a new
# vehicle clock, not a delay (a radio buffers seconds, not minutes).
NEW_CLOCK_S = 60.0


def on_vehicle_clock(receive_s: ArrayLike, vehicle_s: ArrayLike) -> Array:
    """Times (s, on the receive clock) spaced as the vehicle's clock says."""
    r = np.asarray(receive_s, dtype=np.float64)
    v = np.asarray(vehicle_s, dtype=np.float64)
    out = r.copy()
    ok = np.flatnonzero(np.isfinite(v) & (v > 0))
    if ok.size == 0:
        return out
    rv, vv = r[ok], v[ok]
    step_v, step_r = np.diff(vv), np.diff(rv)
    new = (step_v < 0) | (np.abs(step_v - step_r) > NEW_CLOCK_S)
    stretch = np.concatenate([[0], np.cumsum(new)])
    delay = rv - vv
    # The typical delay of each stretch (its median: most packets come straight through,
    # a burst is the exception), so on-time samples stay where they were received and
    # the times stay on the recording's clock (frames, rows); stretches are few.
    bounds = np.concatenate([np.flatnonzero(np.concatenate([[True], new])), [delay.size]])
    offset = np.array([np.median(delay[a:b]) for a, b in zip(bounds[:-1], bounds[1:])])
    out[ok] = vv + offset[stretch]
    return out
