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
from tests.mav_vehicle import MavVehicle
from tests.twin_flights import SMALL_CAMERAS

pytestmark = pytest.mark.timeout(600)  # the twin flight, on a loaded machine

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


@pytest.fixture(scope="module")
def twin_session(tmp_path_factory):
    """A twin flight the station recorded (TIMESYNC on), with the twin's ULog of it in
    the session as a download puts it: the session folder and the link's clock report."""
    tmp = tmp_path_factory.mktemp("twin")
    sd_card = tmp / "sd"
    settings = station_settings(
        "sim",
        tmp / "sessions",
        **{
            "link.timesync_hz": 5.0,
            "twin.flight_log_dir": str(sd_card),
            "recording.auto_record_on_arm": True,
            "recording.post_disarm_tail_s": 0.5,
            "recording.rate_hz": 30,
            **SMALL_CAMERAS,
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
    folder = tmp / "sessions" / sid
    shutil.copy(ulog, folder / "onboard.ulg")
    return folder, clock


def test_a_twin_flight_log_lies_on_the_session_clock(twin_session):
    """The twin's ULog is read onto the session clock: the log's attitude matches the
    tlog's ATTITUDE at no shift, and each ATTITUDE arrived about when the log made it."""
    folder, clock = twin_session
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


def test_export_adds_the_high_rate_streams(twin_session, tmp_path):
    from mcap.reader import make_reader

    from fpv_station.learn.export import ExportOptions, export_recordings

    folder, _ = twin_session
    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    arm = meta["arming"]["t_s"]
    export_recordings([folder], "mcap", tmp_path / "mcap", ExportOptions(task_id=1))
    (path,) = sorted((tmp_path / "mcap").glob("*.mcap"))
    times: dict[str, list[int]] = {}
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages():
            times.setdefault(channel.topic, []).append(message.log_time)
            if channel.topic == "/onboard/imu":
                last_imu = json.loads(message.data)
                if len(times[channel.topic]) == 1:
                    first_imu = last_imu
    imu = np.array(times["/onboard/imu"]) * 1e-9 - meta["start_wall"]  # session clock
    assert {f"/onboard/{s}" for s in ("imu", "rates", "rates_setpoint", "motors", "rc")} <= set(
        times
    )
    # At the log's native rate (of the vehicle's clock: the twin's runs slow when the
    # machine is loaded), inside the flight, on the frames' clock.
    assert (imu.size - 1) / (last_imu["boot_s"] - first_imu["boot_s"]) >= 249.0
    # Within the flight's rows, as its frames and packets are (one Unix-shifted clock).
    rows = np.array(times["/telemetry"]) * 1e-9 - meta["start_wall"]
    assert rows[0] - 1e-6 <= imu[0] and imu[-1] <= rows[-1] + 1e-6
    assert imu[0] == pytest.approx(max(arm, imu[0]), abs=0.5)
    assert set(first_imu) >= {"t_s", "boot_s", "gyro_x_rad_s", "accel_z_m_s2"}
    assert first_imu["t_s"] == pytest.approx(imu[0], abs=1e-3)

    import pyarrow.parquet as pq

    out = tmp_path / "lerobot"
    export_recordings([folder], "lerobot", out, ExportOptions(task_id=1, fps=10))
    series = out / "onboard" / "chunk-000" / "episode_000000"
    imu_t = pq.read_table(series / "imu.parquet").to_pandas()
    windows = pq.read_table(series / "frame_windows.parquet").to_pandas()
    data = pq.read_table(next((out / "data").rglob("*.parquet"))).to_pandas()
    assert len(windows) == len(data)
    # The windows split the series among the frames, each ending at its frame.
    assert windows["imu.from"].iloc[0] == 0 and windows["imu.to"].iloc[-1] == len(imu_t)
    assert (windows["imu.from"].iloc[1:].to_numpy() == windows["imu.to"].iloc[:-1].to_numpy()).all()
    k = len(data) // 2
    w = imu_t.iloc[windows["imu.from"][k] : windows["imu.to"][k]]
    assert (
        len(w) >= 5
    )  # 250 Hz of the twin's clock over a 10 fps frame (its clock runs slow when loaded)
    assert (w["session_time_s"] <= data["session_time_s"][k] + 1e-9).all()
    assert (w["session_time_s"] > data["session_time_s"][k - 1]).all()
    card = (out / "README.md").read_text()
    assert "frame_windows.parquet" in card and "| `imu` |" in card


def test_analysis_plots_imu_and_rate_tracking(twin_session, tmp_path):
    from PIL import Image

    from fpv_station.analysis.cli import write_onboard_figures
    from fpv_station.analysis.plots import SIZE_PX

    folder, _ = twin_session
    (png,) = write_onboard_figures([folder], tmp_path)
    assert png.name.endswith("_onboard.png")
    with Image.open(png) as im:
        assert im.size == SIZE_PX
        # Drawn, not blank: the traces' colours are in it.
        assert len(im.convert("RGB").getcolors(1 << 20)) > 50
    assert write_onboard_figures([DATAFLASH.parent], tmp_path) == []  # no session there


class LoggingArduCopter(MavVehicle):
    """An ArduCopter whose boot clock and ATTITUDE are those of the real DataFlash log:
    it sends, at its boot time, the attitude the log's ATT says it had then."""

    def __init__(self, att, **kw):
        super().__init__(autopilot="ardupilot", **kw)
        self.att = att
        self.boot_mono = time.monotonic() - (att.boot_s[0] - 4.0)  # boots 4 s before ATT

    def build(self, name):
        if name == "ATTITUDE":
            b = self.boot_s()
            roll = float(np.interp(b, self.att.boot_s, self.att.columns["roll_rad"]))
            pitch = float(np.interp(b, self.att.boot_s, self.att.columns["pitch_rad"]))
            return self.mav.attitude_encode(int(b * 1000), roll, pitch, 0.0, 0.0, 0.0, 0.0)
        return super().build(name)


def test_a_dataflash_log_agrees_with_the_tlog_within_20_ms(tmp_path):
    """The real ArduCopter log's ATT against the ATTITUDE the vehicle sent on the link,
    through TIMESYNC: the same instants, to within 20 ms."""
    att = read_onboard_log(DATAFLASH).streams["attitude"]
    root = tmp_path / "sessions"
    with LoggingArduCopter(att) as v:
        settings = station_settings(
            v.station_source, root, **{"link.timesync_hz": 10.0, "recording.rate_hz": 50}
        )
        with run_uvicorn(create_app(settings)) as base:
            assert httpx.post(f"{base}/api/recording/start").status_code == 200
            assert wait_until(lambda: v.boot_s() > att.boot_s[-1] + 1.0, 60)
            sid = httpx.post(f"{base}/api/recording/stop").json()["last_stop"]["id"]
    folder = root / sid
    shutil.copy(DATAFLASH, folder / "onboard.bin")
    got = write_alignment(folder)
    assert got.format == "dataflash" and got.clock == "timesync", got
    assert got.attitude_samples >= 20, got
    assert abs(got.attitude_lag_ms) <= 20.0, got
    assert got.attitude_rms_deg < 1.0, got
