"""The vehicle's boot clock measured with TIMESYNC: real packets over real sockets, a
vehicle whose clock drifts, a link shared with other answerers, one that never answers."""

import csv
import json
import time

import httpx
import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.recording import layout
from fpv_station.companion.timesync import TimeSync, VehicleClock
from fpv_station.server.app import create_app
from tests.helpers import run_uvicorn, station_settings, wait_until
from tests.mav_vehicle import PX4_ONBOARD_RATES_HZ, MavVehicle, timesync_v2
from tests.mav_vehicle import running_link as link_running


def running_link(source, **kw):
    kw.setdefault("timesync_hz", 10.0)
    return link_running(source, **kw)


class SharedLink(MavVehicle):
    """An autopilot (1/1) on a link it shares: its companion computer (1/191) and another
    vehicle (2/1) answer our requests too, first and on their own clocks (a router passes
    our broadcast request to every system), and the autopilot also answers another
    ground station (255/190), mirroring a ts1 equal to ours."""

    def __init__(self, **kw):
        super().__init__(**kw)
        self.companion = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
        self.other = mavlink.MAVLink(None, srcSystem=2, srcComponent=1)

    def _handle(self, msg):
        if msg.get_type() == "TIMESYNC" and msg.tc1 == 0:
            to = (msg.get_srcSystem(), msg.get_srcComponent())
            self.inject(timesync_v2(self.companion, time.time_ns(), msg.ts1, *to)(0))
            self.inject(timesync_v2(self.other, 7_000_000_000, msg.ts1, *to)(0))
            late = int(self.boot_s() * 1e9) + 3_000_000_000
            self.send_raw(timesync_v2(self.mav, late, msg.ts1, 255, 190))
        super()._handle(msg)


def test_offset_and_drift_of_a_drifting_vehicle_on_a_shared_link():
    # Its clock runs 1 % fast (a real crystal's is parts per million; the twin's sim
    # clock on a loaded machine, percents): the station's runs -9901 ppm against it.
    # It also streams PX4's own TIMESYNC requests (tc1 = 0), which are not answers.
    rates = {**PX4_ONBOARD_RATES_HZ, "ATTITUDE": 20.0, "GLOBAL_POSITION_INT": 10.0}
    with SharedLink(clock_rate=1.01, rates_hz=rates) as v, running_link(v.station_source) as link:
        assert wait_until(lambda: link.timesync.report().method == "timesync", 20)
        assert wait_until(lambda: (link.timesync.report().span_s or 0) >= 12, 60)
        r = link.timesync.report()
        assert r.drift_ppm == pytest.approx(1e6 / 1.01 - 1e6, abs=3000), r
        # The vehicle booted at boot_mono on the station's clock; the fitted line may be
        # off by about half the round trips it kept, here on one machine.
        assert abs(r.offset_s - v.boot_mono) < 0.05 + r.rtt_median_ms * 1e-3, r
        assert r.answers > 10 and r.ignored >= 3 * r.answers - 3, r
        assert r.rtt_min_ms <= r.rtt_median_ms < 2000
        assert "fitted to" in r.reason
        # The station's map of a vehicle time agrees with the vehicle's own clock.
        boot = v.boot_s()
        assert float(r.station_s(boot)) == pytest.approx(time.monotonic(), abs=0.1)


def test_a_vehicle_that_never_answers_falls_back_and_says_so():
    with MavVehicle(timesync="none") as v, running_link(v.station_source) as link:
        assert wait_until(lambda: link.timesync.report().requests >= 5, 20)
        assert any(m.get_type() == "TIMESYNC" for m in list(v.received))
        r = link.timesync.report()
        assert r.method == "delay" and r.offset_s is None and r.drift_ppm is None
        assert "did not answer TIMESYNC" in r.reason and "shortest delay" in r.reason


def test_old_ardupilot_answers_to_no_one_over_mavlink1():
    with (
        MavVehicle(autopilot="ardupilot", mavlink1=True, timesync="untargeted") as v,
        running_link(v.station_source) as link,
    ):
        assert wait_until(lambda: link.timesync.report().answers >= 3, 20)
        r = link.timesync.report()
        assert r.method == "timesync" and r.drift_ppm == 0.0  # too short to measure it
        assert abs(r.offset_s - v.boot_mono) < 0.05 + r.rtt_median_ms * 1e-3, r


def test_exchange_off():
    with MavVehicle() as v, running_link(v.station_source, timesync_hz=0) as link:
        assert wait_until(lambda: link.state.get() is not None, 20)
        time.sleep(0.5)
        assert not any(m.get_type() == "TIMESYNC" for m in list(v.received))
        assert "off" in link.timesync.report().reason


def test_slow_trips_do_not_move_the_fit_and_a_reboot_starts_again():
    ts = TimeSync()
    boot0 = 100.0  # the station's time at the vehicle's boot
    t = 1000.0
    for k in range(200):  # 20 s at 10 Hz, every third trip held up 300 ms on the way back
        slow = 0.3 if k % 3 == 0 else 0.0
        ts.sent(k, t)
        v = (t + 0.001 - boot0) * 1.0001  # made 1 ms after it was sent
        assert ts.answered(int(v * 1e9), k, t + 0.002 + slow)
        t += 0.1
    r = ts.report()
    assert r.drift_ppm == pytest.approx(1e6 / 1.0001 - 1e6, abs=5)
    assert r.offset_s == pytest.approx(boot0, abs=0.0015)
    assert r.rtt_min_ms == pytest.approx(2.0, abs=0.01)
    assert not ts.answered(5, 12345, t)  # no such request
    ts.sent(999, t)
    assert ts.answered(int(0.5e9), 999, t + 0.001)  # the clock went back: rebooted
    r = ts.report()
    assert r.reboots == 1 and r.offset_s == pytest.approx(t + 0.0005 - 0.5)
    assert r.ignored == 1


def _status_and_session(v, root, **overrides):
    settings = station_settings(
        v.station_source, root, **{"link.timesync_hz": 10.0, "recording.rate_hz": 20, **overrides}
    )
    with run_uvicorn(create_app(settings)) as base:
        status = lambda: httpx.get(f"{base}/api/status").json()  # noqa: E731
        assert wait_until(lambda: status()["vehicle_clock"]["requests"] >= 3, 20)
        assert httpx.post(f"{base}/api/recording/start").status_code == 200
        if v.timesync == "none":
            time.sleep(1.0)
        else:  # until the drift is measured
            assert wait_until(lambda: "fitted" in status()["vehicle_clock"]["reason"], 30)
        sid = httpx.post(f"{base}/api/recording/stop").json()["last_stop"]["id"]
        clock = status()["vehicle_clock"]
    meta = json.loads((root / sid / layout.SESSION_JSON).read_text())
    with open(root / sid / layout.TELEMETRY_CSV, newline="") as f:
        rows = list(csv.DictReader(f))
    return clock, meta, rows


def test_status_and_session_json_report_the_measured_clock(tmp_path):
    with MavVehicle(clock_rate=1.01) as v:
        clock, meta, rows = _status_and_session(v, tmp_path)
    assert clock["method"] == "timesync" and abs(clock["offset_s"] - v.boot_mono) < 0.05
    boot = meta["clock"]["vehicle_boot"]
    assert boot["method"] == "timesync" and boot["answers"] >= 20, (boot, clock)
    assert boot["drift_ppm"] == pytest.approx(1e6 / 1.01 - 1e6, abs=3000), (boot, clock)
    # On the session clock: each row's ATTITUDE was made (the vehicle's time_boot_ms,
    # mapped) before the row's instant, and not long before (20 Hz, rows at 20 Hz).
    t = np.array([float(r["t_s"]) for r in rows])
    made = VehicleClock(**boot).station_s(
        np.array([float(r["attitude.time_boot_ms"]) for r in rows]) * 1e-3
    )
    late = t - made
    assert late.min() > -0.01 and np.median(late) < 0.15, (late.min(), np.median(late))
    # A replay of the session's tlog reads the same exchange back (our requests were
    # recorded with the answers), on the log's own clock.
    tlog = tmp_path / meta["id"] / layout.MAVLINK_TLOG
    with running_link(f"replay:{tlog}?speed=0") as replay:
        assert wait_until(lambda: replay.health().replay_done, 30)
        again = replay.timesync.report()
    assert again.method == "timesync" and again.answers >= 5, again
    # Its times are the log's (the station's Unix time): less the session's start, the
    # session clock, where both mappings put the session's ATTITUDE alike.
    b = np.array([float(r["attitude.time_boot_ms"]) for r in rows]) * 1e-3
    replayed = again.station_s(b) - meta["start_wall"]
    assert np.abs(replayed - made).max() < 0.03, np.abs(replayed - made).max()


def test_status_and_session_json_say_when_the_vehicle_never_answers(tmp_path):
    with MavVehicle(timesync="none") as v:
        clock, meta, _ = _status_and_session(v, tmp_path)
    for report in (clock, meta["clock"]["vehicle_boot"]):
        assert report["method"] == "delay" and report["offset_s"] is None
        assert "did not answer TIMESYNC" in report["reason"]


def test_the_twin_answers_on_its_simulated_clock(tmp_path):
    # The twin's boot clock is its simulation time, at twice real time here (less when
    # the machine cannot keep up): the station measures whatever rate it runs at.
    settings = station_settings(
        "sim", tmp_path, **{"link.timesync_hz": 10.0, "twin.realtime_factor": 2.0}
    )
    app = create_app(settings)
    with run_uvicorn(app) as base:
        status = lambda: httpx.get(f"{base}/api/status").json()["vehicle_clock"]  # noqa: E731
        assert wait_until(lambda: "fitted" in status()["reason"], 40)
        r = VehicleClock(**status())
        assert r.answers >= 3 and r.drift_ppm != 0.0, r
        # Its time now, mapped, is now: within the fit's scatter (the twin steps its
        # clock in ticks, and in jumps when it falls behind on a loaded machine).
        sim = app.state.station.twin.sim
        err = float(r.station_s(sim.t_s)) - time.monotonic()
        assert abs(err) < 0.3 + 3 * r.residual_ms * 1e-3, (err, r)


def test_a_clock_that_drops_time_is_mapped_through_its_round_trips():
    """The twin's simulated clock on a loaded machine: it loses 0.25 s at a time. No line
    fits it; the kept round trips map it, between them and beyond them."""
    ts = TimeSync()
    t, lost, v = 500.0, 0.0, 0.0
    for k in range(300):  # 30 s at 10 Hz, 0.25 s lost every 5 s: its clock stands still
        if k and k % 50 == 0:
            lost += 0.25
        ts.sent(k, t)
        v = max(v, t + 0.0005 - 400.0 - lost)
        assert ts.answered(int(v * 1e9), k, t + 0.001)
        t += 0.1
    r = ts.report()
    assert r.knots and "strays" in r.reason
    # 523 s: between two drops (at 520 and 525), between two kept trips (522, 524).
    v_523 = 523.0005 - 400.0 - 1.0
    assert float(r.station_s(v_523)) == pytest.approx(523.0, abs=0.005)
    line = r.model_copy(update={"knots": None})
    assert abs(float(line.station_s(v_523)) - 523.0) > 0.01  # which no line gets
    assert float(r.shifted(500.0).station_s(v_523)) == pytest.approx(23.0, abs=0.005)
