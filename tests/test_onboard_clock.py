"""The onboard log read onto the session clock: a real ArduCopter DataFlash log through
DFReader, and the twin's ULog from a flight the station recorded, aligned by TIMESYNC and
checked against the tlog's ATTITUDE."""

from __future__ import annotations

import json
import math
import shutil
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from fpv_station.analysis.onboard_log import (
    OnboardLogError,
    read_onboard_log,
    write_alignment,
)
from fpv_station.companion.recording import layout
from fpv_station.server.app import create_app
from tests.helpers import run_uvicorn, station_settings, wait_until

DATAFLASH = Path(__file__).parent / "data" / "dataflash" / "arducopter.bin"


def test_a_real_dataflash_log_reads_into_the_streams():
    log = read_onboard_log(DATAFLASH)
    assert log.format == "dataflash"
    assert set(log.streams) == {"imu", "attitude", "rates", "rates_setpoint", "motors", "rc"}
    imu, att = log.streams["imu"], log.streams["attitude"]
    # Its first IMU and ATT records, as mavlogdump prints them (TimeUS 81794643, 81795644).
    assert imu.boot_s[0] == pytest.approx(81.794643)
    assert imu.columns["gyro_x_rad_s"][0] == pytest.approx(-0.1165708527)
    assert imu.columns["accel_z_m_s2"][0] == pytest.approx(-9.7809944)
    assert att.boot_s[0] == pytest.approx(81.795644)
    assert att.columns["roll_rad"][0] == pytest.approx(math.radians(-7.18))
    assert log.streams["rc"].columns["ch_0_us"][0] == 1515
    assert log.streams["motors"].columns["motor_0"][0] == 1560
    # Old ArduCopter: no RATE message, rate targets from PIDR/PIDP/PIDY, rates the gyro's.
    sp = log.streams["rates_setpoint"]
    assert sp.columns["roll_rad_s"][0] == pytest.approx(math.radians(-3.622222424))
    assert np.array_equal(log.streams["rates"].columns["roll_rad_s"], imu.columns["gyro_x_rad_s"])
    assert all(np.all(np.diff(s.boot_s) >= 0) for s in log.streams.values())


def test_neither_format_is_a_clear_error(tmp_path):
    bad = tmp_path / "onboard.bin"
    bad.write_bytes(b"\xa3\x95" + bytes(range(200)))  # a DataFlash start, then garbage
    with pytest.raises(OnboardLogError, match="onboard.bin"):
        read_onboard_log(bad)
    other = tmp_path / "onboard.log"
    other.write_bytes(b"not a log")
    with pytest.raises(OnboardLogError, match="neither a ULog nor a DataFlash"):
        read_onboard_log(other)


def test_a_twin_flight_log_lies_on_the_session_clock(tmp_path):
    """The station records a twin flight (TIMESYNC on); the twin's ULog of it, put in the
    session as a download would, is read onto the session clock: the log's attitude
    matches the tlog's ATTITUDE at no shift, and each ATTITUDE arrived after the log says
    it was made."""
    sd_card = tmp_path / "sd"
    settings = station_settings(
        "sim",
        tmp_path / "sessions",
        **{
            "link.timesync_hz": 5.0,
            "twin.flight_log_dir": str(sd_card),
            "recording.auto_record_on_arm": True,
            "recording.post_disarm_tail_s": 0.5,
            "recording.rate_hz": 30,
        },
    )
    app = create_app(settings)
    with run_uvicorn(app) as base:
        twin = app.state.station.twin
        status = lambda: httpx.get(f"{base}/api/status").json()  # noqa: E731
        assert wait_until(lambda: "fitted" in status()["vehicle_clock"]["reason"], 40)
        assert wait_until(lambda: twin.arm(True)[0], 20)
        with twin.lock:
            assert twin.sim.takeoff(2.0)[0]
        time.sleep(2.0)
        assert twin.set_mode("STABILIZED")[0]
        for roll in (0.5, -0.5, 0.5, 0.0):  # rolls to match the two attitudes by
            twin.set_sticks(roll, 0.0, 0.0, 0.5)
            time.sleep(0.4)
        assert twin.set_mode("POSCTL")[0]
        with twin.lock:
            assert twin.sim.land()[0]
        assert wait_until(lambda: not twin.sim.commander.armed[0], 120)
        rec = lambda: httpx.get(f"{base}/api/recording").json()  # noqa: E731
        assert wait_until(lambda: not rec()["recording"] and rec()["last_stop"], 20)
        sid = rec()["last_stop"]["id"]
        assert wait_until(lambda: twin.flight_log.logs and not twin.flight_log.writing, 10)
        ulog = twin.flight_log.logs[-1].path
        clock = status()["vehicle_clock"]
    folder = tmp_path / "sessions" / sid
    shutil.copy(ulog, folder / "onboard.ulg")
    got = write_alignment(folder)
    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    assert meta["onboard_alignment"] == got.model_dump()
    assert got.format == "ulog" and got.clock == "timesync"
    assert got.rates_hz["imu"] >= 249.0 and got.rates_hz["rates_setpoint"] >= 249.0
    assert got.attitude_samples > 20
    # The two are one vehicle clock: the best match is at no shift, to a physics step.
    assert abs(got.attitude_lag_ms) <= 20.0, got
    assert got.attitude_rms_deg < 0.5, got
    # On the session clock each ATTITUDE arrived about when the log made it (the twin is
    # on this machine), within the mapping's stated error: on a loaded machine the
    # twin's clock drops up to 0.25 s at a time, more than once between two round trips
    # (it is then mapped through them, `knots`, and strays `residual_ms` from a line).
    slack_ms = 100 + (clock["residual_ms"] if clock["knots"] else 0)
    assert got.arrival_delay_ms_min is not None  # at a drop, the mapping's error shows
    assert abs(got.arrival_delay_ms_median) < slack_ms, (got, clock)
    # The log spans the armed part of the session: from arming (the session starts when
    # the station hears it armed) to disarm.
    assert -1.5 - slack_ms / 1e3 < got.start_s < meta["arming"]["t_s"] + slack_ms / 1e3
    assert got.end_s <= meta["duration_s"] + slack_ms / 1e3
