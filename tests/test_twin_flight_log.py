"""The twin's own flight log: a PX4 ULog per armed period, read back with pyulog."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pyulog import ULog

from fpv_station.twin.runner import Twin

HIGH_RATE = (
    "sensor_combined",
    "vehicle_attitude",
    "vehicle_angular_velocity",
    "vehicle_rates_setpoint",
    "actuator_motors",
)
SLOW = ("vehicle_attitude_setpoint", "vehicle_local_position", "input_rc", "actuator_outputs")


def _fly(twin: Twin, hover_s: float) -> tuple[float, float]:
    """Take off, hover, land and disarm; returns the sim times of arming and disarm."""
    twin.step_for(3.0)  # a GPS fix first
    ok, why = twin.sim.arm(True)
    assert ok, why
    armed_at = twin.sim.t_s
    assert twin.sim.takeoff(3.0)[0]
    twin.step_for(hover_s)
    assert twin.sim.land()[0]
    for _ in range(40):
        twin.step_for(0.5)
        if not twin.sim.commander.armed[0]:
            return armed_at, twin.sim.t_s
    pytest.fail("the twin did not disarm after landing")


def _topics(path: Path) -> dict[str, dict[str, np.ndarray]]:
    return {d.name: d.data for d in ULog(str(path)).data_list}


def test_one_ulog_per_armed_period_readable_by_pyulog(tmp_path: Path) -> None:
    twin = Twin(flight_log_dir=tmp_path)
    try:
        armed_at, disarmed_at = _fly(twin, 4.0)
        assert twin.flight_log is not None and not twin.flight_log.writing
        _fly(twin, 1.0)
    finally:
        twin.stop()
    logs = twin.flight_log.logs
    assert [e.id for e in logs] == [1, 2]
    assert all(e.size_bytes == e.path.stat().st_size > 0 for e in logs)
    assert logs[0].time_utc > 0

    ulog = ULog(str(logs[0].path))
    assert ulog.msg_info_dict["sys_name"] == "fpv-station twin"
    data = _topics(logs[0].path)
    assert set(HIGH_RATE + SLOW) <= set(data)
    for name in HIGH_RATE:
        t_s = data[name]["timestamp"] * 1e-6
        # On the twin's boot clock, from arming to disarm, at the physics rate.
        assert t_s[0] == pytest.approx(armed_at, abs=0.05)
        assert t_s[-1] == pytest.approx(disarmed_at, abs=0.25)
        assert (len(t_s) - 1) / (t_s[-1] - t_s[0]) >= 249.0
    for name in SLOW:
        t_s = data[name]["timestamp"] * 1e-6
        assert (len(t_s) - 1) / (t_s[-1] - t_s[0]) >= 45.0

    imu = data["sensor_combined"]
    # Standing on the ground the accelerometer reads -g on body z (FRD).
    assert imu["accelerometer_m_s2[2]"][0] == pytest.approx(-9.81, abs=0.05)
    # The motors spun in the air, and the rate setpoints moved.
    motors = data["actuator_motors"]["control[0]"]
    assert motors.max() > 0.3
    q = np.stack([data["vehicle_attitude"][f"q[{i}]"] for i in range(4)])
    assert np.allclose(np.linalg.norm(q, axis=0), 1.0, atol=1e-5)
    # The local position climbed to about the take-off height (NED: z negative up).
    assert data["vehicle_local_position"]["z"].min() < -2.0
    # RC: throttle channel in PWM.
    assert 900 <= data["input_rc"]["values[2]"].max() <= 2100


def test_no_log_without_arming_and_none_when_off(tmp_path: Path) -> None:
    twin = Twin(flight_log_dir=tmp_path / "on")
    off = Twin(flight_log=False)
    try:
        twin.step_for(2.0)
        off.step_for(1.0)
    finally:
        twin.stop()
        off.stop()
    assert twin.flight_log is not None and twin.flight_log.logs == []
    assert off.flight_log is None and off.sim.on_physics_step is None
