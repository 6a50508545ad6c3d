"""Analysis' sample times and the rows agree under load: a twin flight recorded by a real
station while two CPU-hog processes run (a 2-core machine at load 8), then loaded for
analysis. Each GPS sample is timed by the vehicle's clock placed on the session clock
(`analysis.vehicle_clock`); it must lie between the arrival of the sample before it and
the row that first holds it, so that at any instant the sample analysis measures is the
row's or the next (loaded, the station reads stretches of packets a few tenths of a
second late, and the on-time packets after them put those stretches 0.3-0.5 s, two
samples, before their rows)."""

from __future__ import annotations

import contextlib
import subprocess
import sys

import numpy as np
import pytest

from fpv_station.analysis.track import load_session_dir
from tests.twin_flights import NO_CAMERAS, recorded_twin_flight


@contextlib.contextmanager
def cpu_hogs(n: int = 2):
    hogs = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()


@pytest.mark.timeout(400)
def test_sample_times_stay_within_a_sample_of_their_rows_under_load(tmp_path):
    with cpu_hogs(2), recorded_twin_flight(tmp_path, 1, NO_CAMERAS, timeout_s=240) as flight:
        folder = flight.folder
    track = load_session_dir(folder)
    rows = track.row_t_s
    assert len(track) > 100
    # The previous arrival: the last row time before this sample's own.
    before = np.searchsorted(rows, rows, side="left") - 1
    previous = np.where(before >= 0, rows[np.maximum(before, 0)], -np.inf)
    early = rows - track.t_s
    late_by = previous - track.t_s
    assert early.min() >= 0.0, early.min()  # never after the row that first held it
    assert late_by.max() <= 1e-9, (late_by.max(), early.max())
