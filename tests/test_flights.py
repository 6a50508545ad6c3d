"""Flights split out of one recording: a real .tlog (packed by pymavlink's encoder) holding
a motor test on the ground, three sorties with the vehicle walked between them, a GPS
altitude blip on the pad, and a tail recorded after the last disarm."""

from __future__ import annotations

import numpy as np
import pytest

from fpv_station.analysis.flights import Flight, split_flights, track_flights
from fpv_station.analysis.track import load_track
from tests import synthetic as syn
from tests.known_flights import SORTIES_TRUTH, three_sorties


@pytest.fixture(scope="module")
def tlog_track(tmp_path_factory):
    path = tmp_path_factory.mktemp("flights") / "sorties.tlog"
    syn.write_tlog(three_sorties(), path, gps_hz=10.0)
    return load_track(path)


def test_tlog_with_several_sorties_splits_into_its_flights(tlog_track):
    flights = track_flights(tlog_track)
    assert [f.number for f in flights] == [1, 2, 3]  # the motor test is no flight
    t = tlog_track.t_s
    gps_period = 0.1
    # The tlog is read as a recorder's rows (30 a second): a sample is on the first row
    # after it arrived, up to one row period after the log's time.
    row = 1 / 30 + 1e-3
    for f, (arm, takeoff, landing, disarm) in zip(flights, SORTIES_TRUTH):
        # Armed state comes from 1 Hz HEARTBEATs sent on the second, as the vehicle armed.
        assert arm <= f.arm_s <= arm + row
        assert disarm - gps_period <= f.disarm_s <= disarm - gps_period + row  # last armed
        # Take-off/landing: the first/last GPS sample more than 0.5 m up; the pilot's
        # altitude (GLOBAL_POSITION_INT) is the one received before the GPS sample, so
        # up to one GPS period late.
        assert takeoff <= f.takeoff_s <= takeoff + 2 * gps_period + row
        assert landing - gps_period - 1e-3 <= f.landing_s <= landing + gps_period + row
        # Indices and times agree, and the slice is the armed period.
        for i, s in ((f.arm, f.arm_s), (f.takeoff, f.takeoff_s), (f.landing, f.landing_s)):
            assert t[i] == s
        assert tlog_track.armed[f.samples].all()
        assert not tlog_track.armed[f.arm - 1] and not tlog_track.armed[f.disarm + 1]
    # The post-disarm tail belongs to no flight.
    assert flights[-1].disarm < len(tlog_track) - 100


def test_a_flight_selects_its_own_track(tlog_track):
    second = track_flights(tlog_track)[1]
    part = tlog_track.select(second.samples)
    assert part.armed.all()
    assert part.t_s[0] == second.arm_s and part.t_s[-1] == second.disarm_s
    # Splitting the flight's own track finds the same flight, shifted by its start.
    (again,) = track_flights(part)
    assert again.takeoff == second.takeoff - second.arm
    assert again.landing_s == second.landing_s


def test_gps_altitude_alone_decides_when_there_is_no_pilot_altitude(tlog_track):
    from dataclasses import replace

    gps_only = replace(tlog_track, relative_alt_m=np.full(len(tlog_track), np.nan))
    a = [(f.arm, f.disarm) for f in track_flights(gps_only)]
    assert a == [(f.arm, f.disarm) for f in track_flights(tlog_track)]


def test_times_are_on_the_clock_given():
    # The vehicle's clock (say time_boot_ms) can run apart from the receive time.
    t = np.arange(0, 30, 0.1)
    armed = (t >= 2) & (t < 28)
    h = np.clip(np.minimum(t - 5, 25 - t), 0, 3)
    (f,) = split_flights(t + 1000.0, armed, h)
    assert f.arm_s == pytest.approx(1002.0)
    assert f.takeoff_s == pytest.approx(1005.6)  # first sample > 0.5 m
    assert f.landing_s == pytest.approx(1024.4)
    assert f.airborne_s == pytest.approx(18.8)


def test_a_log_that_ends_armed_ends_its_flight_at_the_last_sample():
    t = np.arange(0, 10, 0.1)
    armed = t >= 1
    h = np.where(t > 3, 2.0, 0.0)
    (f,) = split_flights(t, armed, h)
    assert (f.arm, f.disarm, f.landing) == (10, t.size - 1, t.size - 1)


def test_without_heartbeat_height_alone_decides():
    t = np.arange(0, 10, 0.1)
    h = np.where((t > 3) & (t < 7), 2.0, 0.0)
    (f,) = split_flights(t, np.zeros(t.size, bool), h)
    assert (f.arm, f.disarm) == (0, t.size - 1)
    assert f.takeoff_s == pytest.approx(3.1) and f.landing_s == pytest.approx(6.9)


def test_unknown_heights_and_ground_only_give_no_flight():
    t = np.arange(0, 10, 0.1)
    armed = (t > 1) & (t < 9)
    assert split_flights(t, armed, np.full(t.size, np.nan)) == []
    assert split_flights(t, armed, np.full(t.size, 100.0)) == []  # armed on a hill: no climb
    assert split_flights([], [], []) == []
    with pytest.raises(ValueError):
        split_flights(t, armed[:-1], t)


def test_flight_is_a_small_frozen_record():
    f = Flight(1, 0, 9, 2, 7, 0.0, 0.9, 0.2, 0.7)
    assert f.samples == slice(0, 10)
    with pytest.raises(AttributeError):
        f.number = 2
