"""Quality measures gathered while recording: row-to-frame skew and link-loss intervals."""

from __future__ import annotations

import threading
from array import array

import numpy as np

from fpv_station.companion.recording.meta import LinkLoss


class SkewStats:
    """Every row's skew for one camera (8 bytes a row: 2.9 MB for an hour at 100 Hz)."""

    def __init__(self) -> None:
        # Rows append (the writer's thread, or a replay's) while session.json is written
        # from another: an array cannot grow while numpy holds its buffer, so both sides
        # take the lock.
        self._lock = threading.Lock()
        self._skews_s = array("d")
        self._max_s: float | None = None

    def add(self, skew_s: float) -> None:
        with self._lock:
            self._skews_s.append(skew_s)
            if self._max_s is None or skew_s > self._max_s:
                self._max_s = skew_s

    @property
    def count(self) -> int:
        return len(self._skews_s)

    def max_s(self) -> float | None:
        return self._max_s

    def p99_s(self) -> float | None:
        with self._lock:
            if not self._skews_s:
                return None
            values = np.array(self._skews_s, dtype=np.float64)  # a copy, under the lock
        return float(np.percentile(values, 99))


class LinkLossTracker:
    """Intervals (session clock) with nothing from the autopilot for longer than `lost_after_s`
    (the link loss, and the shorter telemetry gaps of flags.QUALITY_THRESHOLDS)."""

    def __init__(self, t0_mono: float, lost_after_s: float) -> None:
        self.t0_mono = t0_mono
        self.lost_after_s = lost_after_s
        self.intervals: list[LinkLoss] = []
        self._lost = False

    def update(self, now_mono: float, last_seen_mono: float | None) -> None:
        """Call at every sample with the time of the autopilot's newest message."""
        # Before the first packet the silence counts from the session start.
        since = last_seen_mono if last_seen_mono is not None else self.t0_mono
        silent = now_mono - since > self.lost_after_s
        if silent and not self._lost:
            self._lost = True
            start = max(since, self.t0_mono) - self.t0_mono
            self.intervals.append(LinkLoss(start_s=round(start, 3)))
        elif not silent and self._lost:
            self._lost = False
            self.intervals[-1].end_s = round(max(since, self.t0_mono) - self.t0_mono, 3)

    @property
    def lost(self) -> bool:
        return self._lost
