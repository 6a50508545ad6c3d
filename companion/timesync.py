"""The vehicle's boot clock on the station's clock, measured with MAVLink TIMESYNC.

The link sends TIMESYNC with `tc1 = 0` and `ts1` = a time of ours in ns; the autopilot
answers with `tc1` = its own time in ns since boot and `ts1` mirrored. PX4 and ArduPilot
both count `tc1` from boot in ns (ArduPilot stamps it when the request's bytes arrived);
PX4 from 1.14 and ArduPilot from 4.3 address the answer with `target_system` and
`target_component`, older firmware and MAVLink 1 leave both 0. So an answer is ours when
it comes from the followed autopilot, is addressed to us (or to no one), and mirrors a
`ts1` we sent that has not been answered yet: another ground station's exchange on the
same link mirrors its own `ts1`, and the vehicle's own requests (`tc1 = 0`; PX4 asks
every 100 ms) are not answers.

Each answer is a round trip: sent at `s`, made at `v` on the vehicle, received at `r`
(`s` and `r` on the source's clock: the station's monotonic one, a replay's log time).
`v` happened between `s` and `r`, so at `(s + r) / 2` within half the round trip. A trip
held up on either leg (a busy radio, the autopilot's scheduler, a loaded station) is off
by up to its delay, so only the fastest trip of every `BIN_S` is kept, and of those the
ones within twice their median round trip (a bin whose every trip was held up is not)
are fitted with a line `station = offset_s + v * (1 + drift)`. An autopilot's crystal
keeps to such a line within its round trips; a clock that strays from it by more than
its median round trip does not tick evenly (the twin's simulated clock, which drops
time when a loaded machine holds it up), and is then mapped through the kept round
trips themselves (`knots`, straight between them, the line beyond them). A vehicle
whose clock goes back has rebooted: the fit starts again.

Until an answer comes (or with the exchange off) there is no mapping, and vehicle times
are placed on the session clock by their shortest delay (`analysis.vehicle_clock`);
the report says which is used and why.

`TimeSync` is fed by the link thread only; `report()` is an immutable snapshot any thread
may read.
"""

from __future__ import annotations

import collections
import math
from typing import Literal

import numpy as np
from pydantic import BaseModel

# A round trip longer than this is not a measurement (a link that buffered seconds).
MAX_RTT_S = 2.0
# The fastest round trip of each this-long stretch of the station's clock is kept.
BIN_S = 2.0
# Kept bins: beyond it the oldest go (hours at BIN_S).
MAX_BINS = 4096
# Drift is fitted once the kept samples span this much of the vehicle's clock (a few
# bins); until then the clocks are taken to tick at one rate.
MIN_DRIFT_SPAN_S = 4.0
# Requests sent and not yet answered, remembered by their ts1 (the oldest forgotten).
MAX_PENDING = 64

Method = Literal["timesync", "delay"]


class VehicleClock(BaseModel):
    """How the vehicle's boot clock (`time_boot_ms`, `time_usec`, an onboard log's
    timestamps) is put on the station's clock: `station = offset_s + boot_s * (1 +
    drift_ppm * 1e-6)`. In `/api/status` the station's clock is its monotonic one; in
    session.json the session clock (`t_s`)."""

    method: Method  # "timesync": measured; "delay": each sample's shortest delay
    reason: str
    offset_s: float | None = None  # the station's time at the vehicle's boot time zero
    drift_ppm: float | None = None  # how much faster the station's clock runs, per million
    rtt_min_ms: float | None = None  # the fastest round trip kept
    rtt_median_ms: float | None = None  # the median of the kept round trips
    residual_ms: float | None = None  # RMS distance of the fitted trips from the line
    span_s: float | None = None  # of the vehicle's clock the fitted trips cover
    requests: int = 0
    answers: int = 0  # answers to our requests, used
    # TIMESYNC answers not used: another system's, to another asker, to no request of
    # ours, or too slow to measure
    ignored: int = 0
    reboots: int = 0  # times the vehicle's clock went back (the fit started again)
    # (vehicle s, station s) of the kept round trips when the clock strays from the line
    # by more than its round trips explain; None: the line maps it.
    knots: list[tuple[float, float]] | None = None

    def station_s(self, boot_s: np.ndarray | float) -> np.ndarray:
        """Station times of vehicle boot times (s); NaN without a measured mapping."""
        b = np.asarray(boot_s, dtype=np.float64)
        if self.offset_s is None or self.drift_ppm is None:
            return np.full(b.shape, np.nan)
        rate = 1.0 + self.drift_ppm * 1e-6
        line = self.offset_s + b * rate
        if not self.knots:
            return line
        kv, ks = np.array(self.knots, dtype=np.float64).T
        # Beyond the knots, the line's rate from the nearest one.
        mapped: np.ndarray = np.where(
            b < kv[0],
            ks[0] + (b - kv[0]) * rate,
            np.where(b > kv[-1], ks[-1] + (b - kv[-1]) * rate, np.interp(b, kv, ks)),
        )
        return mapped

    def shifted(self, t0: float) -> VehicleClock:
        """The same mapping on a clock whose zero is at `t0` (a session's start)."""
        if self.offset_s is None:
            return self
        knots = None if self.knots is None else [(v, round(s - t0, 6)) for v, s in self.knots]
        return self.model_copy(update={"offset_s": round(self.offset_s - t0, 6), "knots": knots})


class TimeSync:
    """Round trips in, a fitted mapping out. Only the link thread calls the methods but
    `report()`."""

    def __init__(self, enabled: bool = True) -> None:
        self.enabled = enabled
        self._pending: collections.OrderedDict[int, float] = collections.OrderedDict()
        # (vehicle s, station midpoint s, rtt s): the fastest of each finished bin
        self._bins: collections.deque[tuple[float, float, float]] = collections.deque(
            maxlen=MAX_BINS
        )
        self._bin: int | None = None
        self._best: tuple[float, float, float] | None = None  # the current bin's fastest
        self._last_v: float | None = None
        self.requests = 0
        self.answers = 0
        self.ignored = 0
        self.reboots = 0
        self._report = self._fallback()

    def report(self) -> VehicleClock:
        return self._report

    def reset(self) -> None:
        """Another vehicle clock follows (a replay's next recording)."""
        self._pending.clear()
        self._restart()
        self._report = self._fallback()

    def sent(self, ts1_ns: int, t_send: float) -> None:
        """A request with `ts1_ns` went out at `t_send` (the source's clock)."""
        self._pending[ts1_ns] = t_send
        self._pending.move_to_end(ts1_ns)
        while len(self._pending) > MAX_PENDING:
            self._pending.popitem(last=False)
        self.requests += 1
        if self.answers == 0:
            self._report = self._fallback()

    def answered(self, tc1_ns: int, ts1_ns: int, t_recv: float) -> bool:
        """An answer from the followed autopilot, addressed to us or to no one; False
        when it answers no request of ours (or too late to measure)."""
        t_send = self._pending.pop(ts1_ns, None)
        if t_send is None or not 0.0 <= t_recv - t_send <= MAX_RTT_S or tc1_ns <= 0:
            self.ignored += 1
            return False
        rtt = t_recv - t_send
        v = tc1_ns * 1e-9
        if self._last_v is not None and v < self._last_v:
            self.reboots += 1
            self._restart()
        self._last_v = v
        self.answers += 1
        sample = (v, (t_send + t_recv) / 2, rtt)
        b = math.floor(t_send / BIN_S)
        if b != self._bin:
            if self._best is not None:
                self._bins.append(self._best)
            self._bin, self._best = b, sample
        elif self._best is None or rtt < self._best[2]:
            self._best = sample
        self._report = self._fit()
        return True

    def _restart(self) -> None:
        self._bins.clear()
        self._bin, self._best, self._last_v = None, None, None

    def _fallback(self) -> VehicleClock:
        if not self.enabled:
            why = "the TIMESYNC exchange is off (link.timesync_hz = 0)"
        elif self.requests == 0:
            why = "no TIMESYNC request sent yet"
        else:
            why = f"the vehicle did not answer TIMESYNC ({self.requests} requests)"
        return VehicleClock(
            method="delay",
            reason=f"{why}: vehicle times are placed by their shortest delay",
            requests=self.requests,
            ignored=self.ignored,
            reboots=self.reboots,
        )

    def _fit(self) -> VehicleClock:
        kept = [*self._bins, *([self._best] if self._best is not None else [])]
        s = np.array(kept, dtype=np.float64)
        v, mid, rtt = s[:, 0], s[:, 1], s[:, 2]
        fast = rtt <= 2 * np.median(rtt)  # a bin whose every trip was held up is left out
        if fast.sum() >= 3:
            v, mid, rtt = v[fast], mid[fast], rtt[fast]
        span = float(v.max() - v.min())
        if v.size >= 3 and span >= MIN_DRIFT_SPAN_S:
            vc = v - v.mean()
            rate = float(np.dot(vc, mid - mid.mean()) / np.dot(vc, vc))
            offset = float(mid.mean() - rate * v.mean())
            how = f"fitted to {v.size} fast round trips over {span:.0f} s"
        else:
            rate = 1.0
            k = int(np.argmin(rtt))
            offset = float(mid[k] - v[k])
            how = "the fastest round trip so far; drift not yet measured"
        residual = mid - (offset + rate * v)
        rms = float(np.sqrt(np.mean(residual**2)))
        knots = None
        if v.size >= 3 and rms > max(float(np.median(rtt)), 1e-3):
            order = np.argsort(v)
            knots = [(round(float(v[k]), 6), round(float(mid[k]), 6)) for k in order]
            how += f"; it strays {rms * 1e3:.0f} ms from a line, so mapped through them"
        return VehicleClock(
            method="timesync",
            reason=f"measured by TIMESYNC: {how}",
            offset_s=round(offset, 6),
            drift_ppm=round((rate - 1.0) * 1e6, 3),
            rtt_min_ms=round(float(rtt.min()) * 1e3, 3),
            rtt_median_ms=round(float(np.median(rtt)) * 1e3, 3),
            residual_ms=round(rms * 1e3, 3),
            span_s=round(span, 3),
            requests=self.requests,
            answers=self.answers,
            ignored=self.ignored,
            reboots=self.reboots,
            knots=knots,
        )
