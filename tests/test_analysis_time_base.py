"""Analysis times from the vehicle's own clock: a radio fade of 4.3 s
ends in a burst of the packets it buffered, all with one receive time. Speeds and
durations must come from the vehicle's time_usec / time_boot_ms, not from when the burst
arrived: the GPS says 28 m/s, so must the analysis."""

from __future__ import annotations

import numpy as np
import pytest

from fpv_station.analysis.report import analyze_paths
from fpv_station.analysis.track import load_track
from fpv_station.analysis.vehicle_clock import on_vehicle_clock
from fpv_station.companion.timesync import VehicleClock
from tests import shaped_tlog
from tests.known_flights import DASH_FADE, DASH_SPEED_MPS, dash


@pytest.fixture(scope="module")
def burst_tlog(tmp_path_factory):
    log = shaped_tlog.vehicle_flight(dash(), fade=DASH_FADE, burst_s=1.0)
    return log.write(tmp_path_factory.mktemp("burst") / "burst.tlog")


def test_speed_after_a_burst_is_the_gps_speed_not_the_burst(burst_tlog):
    (r,) = analyze_paths([burst_tlog], "a-to-b", scene=False).results
    assert r.max_speed_mps == pytest.approx(DASH_SPEED_MPS, abs=1.0)  # receive times: ~60 m/s
    assert r.trial_time_s == pytest.approx(20.0, abs=0.5)  # take-off 2.5 s, landing 22.5 s


def test_track_times_are_the_vehicles(burst_tlog):
    track = load_track(burst_tlog)
    steps = np.diff(track.t_s)
    assert steps.min() > 0.15  # 5 Hz GPS, none piled up on one receive time
    # Last GPS before the fade, then the burst's newest: a recorder's rows (and a tlog
    # replayed into them) hold the state at each row's instant, not every packet of a burst.
    assert steps.max() == pytest.approx(16.2 - 11.8, abs=0.01)


def test_vehicle_clock_stretches_and_fallback():
    r = np.array([10.0, 10.2, 10.4, 10.6, 15.0, 15.0, 100.0, 100.2])
    v = np.array([1.0, 1.2, 1.4, 1.6, 4.8, 5.0, 0.5, 0.7])  # a burst, then a reboot
    want = [10.0, 10.2, 10.4, 10.6, 13.8, 14.0, 100.0, 100.2]
    assert on_vehicle_clock(r, v) == pytest.approx(want)
    assert on_vehicle_clock(r, np.zeros(r.size)) == pytest.approx(r)  # no vehicle time


def test_vehicle_clock_at_another_rate_stays_on_the_receive_clock():
    """The twin's simulated clock on a loaded machine runs slow (3 % here), and packets
    come through with a little delay: times are never after a packet arrived, and are
    within that delay of it, not spread around a middle delay (up to 0.9 s off here)."""
    rng = np.random.default_rng(3)
    received = np.arange(0.0, 60.0, 0.2) + rng.uniform(0.0, 0.03, 300)
    vehicle = 4.0 + 0.97 * np.arange(0.0, 60.0, 0.2)
    early = received - on_vehicle_clock(received, vehicle)
    assert early.min() >= 0.0
    assert early.max() < 0.2  # the last 5 s look back (3 % of 5 s, plus the delay)
    assert early[received < 55.0].max() < 0.03


def test_a_measured_vehicle_clock_places_its_stretch_and_not_another():
    """With TIMESYNC's line the boot-clock stretch is placed by it, at the made time
    however late each packet came (a 2 s radio burst included); a stretch on another
    time base (the reboot's new clock) keeps the shortest delay."""
    made = np.arange(5.2, 35.0, 0.2)
    boot_s = (made - 5.0) * 1.001  # booted at session time 5 s, its clock 0.1 % fast
    late = np.where((made > 10) & (made < 12), 12.0 - made, 0.01)  # a burst at 12 s
    received = made + late
    boot = VehicleClock(method="timesync", reason="", offset_s=5.0, drift_ppm=1e6 / 1.001 - 1e6)
    r = np.concatenate([received, [50.0, 50.2]])
    v = np.concatenate([boot_s, [0.5, 0.7]])
    placed = on_vehicle_clock(r, v, boot)
    assert placed[: made.size] == pytest.approx(made, abs=1e-9)
    assert placed[made.size :] == pytest.approx([50.0, 50.2])
    assert on_vehicle_clock(r, v) != pytest.approx(placed)  # the shortest delay differs


def test_a_stretch_read_late_stays_within_a_sample_of_its_rows():
    """A loaded station reads 10 s of 5 Hz samples 0.4 s late each, then on time again
    (the backlog read in order, a millisecond apart): the on-time packets after the
    stretch must not pull it 0.4 s before its rows (two samples): each sample is placed
    after the previous one arrived."""
    vehicle = np.arange(0.0, 40.0, 0.2) + 5.0
    late = (vehicle >= 15.0) & (vehicle < 25.0)
    received = vehicle - 5.0 + np.where(late, 0.4, 0.02)
    for i in range(1, received.size):
        received[i] = max(received[i], received[i - 1] + 0.001)
    t = on_vehicle_clock(received, vehicle)
    assert np.all(t <= received)
    assert np.all(t[1:] >= received[:-1] - 1e-9), (received - t).max()
    assert np.all(np.diff(t) > 0)
