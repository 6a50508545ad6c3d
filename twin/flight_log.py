"""The twin's own flight log, as PX4's logger writes it: one ULog per armed period.

PX4 (SDLOG_MODE 0) starts a log at arming and closes it at disarm; so does the twin. Each
physics step of vehicle 0 adds the high-rate topics (IMU, attitude, body rates and their
setpoints, motor commands) and every fifth step the slower ones (attitude setpoint,
position, RC input, PWM outputs), under PX4's topic and field names and frames (NED
world, FRD body), stamped in µs of the twin's boot clock: the clock its MAVLink
`time_boot_ms` counts, so the log and the telemetry share one vehicle time.

It runs in the twin's thread (`Sim.on_physics_step`); the finished logs are what
`twin.log_server.LogServer` lists and serves.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from fpv_station.twin.sim import Sim
from fpv_station.twin.telemetry import stick_to_pwm
from fpv_station.twin.ulog import Topic, ULogWriter

log = logging.getLogger(__name__)

_SLOW_EVERY = 5  # the slower topics at a fifth of the physics rate (50 Hz at 250 Hz)
_ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_FRD_TO_FLU = np.diag([1.0, -1.0, -1.0])
_FLU_FRD = np.array([1.0, -1.0, -1.0])  # a body vector FLU <-> FRD
_GRAVITY_ENU = np.array([0.0, 0.0, 9.80665])

TOPICS = [
    Topic(
        "sensor_combined",
        (
            ("float[3]", "gyro_rad"),
            ("uint32_t", "gyro_integral_dt"),
            ("int32_t", "accelerometer_timestamp_relative"),
            ("float[3]", "accelerometer_m_s2"),
            ("uint32_t", "accelerometer_integral_dt"),
        ),
    ),
    Topic("vehicle_attitude", (("uint64_t", "timestamp_sample"), ("float[4]", "q"))),
    Topic("vehicle_angular_velocity", (("uint64_t", "timestamp_sample"), ("float[3]", "xyz"))),
    Topic(
        "vehicle_rates_setpoint",
        (("float", "roll"), ("float", "pitch"), ("float", "yaw"), ("float[3]", "thrust_body")),
    ),
    Topic(
        "actuator_motors",
        (
            ("uint64_t", "timestamp_sample"),
            ("uint16_t", "reversible_flags"),
            ("float[4]", "control"),
        ),
    ),
    Topic("vehicle_attitude_setpoint", (("float[4]", "q_d"), ("float[3]", "thrust_body"))),
    Topic(
        "vehicle_local_position",
        (
            ("float", "x"),
            ("float", "y"),
            ("float", "z"),
            ("float", "vx"),
            ("float", "vy"),
            ("float", "vz"),
        ),
    ),
    Topic(
        "input_rc",
        (
            ("uint64_t", "timestamp_last_signal"),
            ("uint16_t", "channel_count"),
            ("int32_t", "rssi"),
            ("uint16_t[8]", "values"),
        ),
    ),
    Topic("actuator_outputs", (("uint32_t", "noutputs"), ("float[4]", "output"))),
]


def quaternion_wxyz(R: np.ndarray) -> tuple[float, float, float, float]:
    """The unit quaternion (w, x, y, z) of rotation matrix `R`, w >= 0 (Shepperd)."""
    m = R
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = ((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s)
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s)
    sign = -1.0 if q[0] < 0 else 1.0
    w, x, y, z = q
    return float(sign * w), float(sign * x), float(sign * y), float(sign * z)


@dataclass(frozen=True)
class LogFile:
    """A finished log: its MAVLink log id (1, 2, ...), file, size and start time (UTC
    seconds, as LOG_ENTRY's time_utc)."""

    id: int
    path: Path
    size_bytes: int
    time_utc: int


class FlightLogger:
    """Writes a ULog per armed period of `sim`'s vehicle 0 into `directory`."""

    def __init__(self, directory: Path, sys_name: str = "fpv-station twin") -> None:
        self.directory = directory
        self.sys_name = sys_name
        self.logs: list[LogFile] = []
        self._file: BinaryIO | None = None
        self._writer: ULogWriter | None = None
        self._path: Path | None = None
        self._time_utc = 0
        self._prev_vel: np.ndarray | None = None
        self._steps = 0
        self.errors = 0

    @property
    def writing(self) -> bool:
        return self._writer is not None

    def erase(self) -> None:
        """Delete the finished logs (LOG_ERASE); the one being written stays."""
        for entry in self.logs:
            entry.path.unlink(missing_ok=True)
        self.logs = []

    def close(self) -> None:
        self._finish()

    def on_step(self, sim: Sim, t_s: float) -> None:
        """After each physics step (the twin's thread): open at arming, sample, close at disarm."""
        armed = bool(sim.commander.armed[0])
        if armed and self._writer is None:
            self._open(t_s)
        elif not armed and self._writer is not None:
            self._finish()
        if self._writer is None:
            return
        try:
            self._sample(sim, t_s)
        except OSError as exc:  # a full disk ends this log; the twin flies on
            self.errors += 1
            log.error("twin flight log %s: %s; closed", self._path, exc)
            self._finish()

    def _open(self, t_s: float) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        number = (self.logs[-1].id if self.logs else 0) + 1
        self._path = self.directory / f"log_{number:03d}.ulg"
        self._time_utc = int(time.time())
        self._file = self._path.open("wb")
        info = {"sys_name": self.sys_name, "ver_hw": "SITL", "sys_toolchain": "python"}
        self._writer = ULogWriter(self._file, int(t_s * 1e6), TOPICS, info)
        self._writer.log_text(int(t_s * 1e6), "logging started at arming")
        self._prev_vel = None
        self._steps = 0

    def _finish(self) -> None:
        if self._file is None or self._path is None:
            return
        self._file.close()
        number = (self.logs[-1].id if self.logs else 0) + 1
        size = self._path.stat().st_size
        self.logs.append(LogFile(number, self._path, size, self._time_utc))
        self._file = self._writer = self._path = None

    def _sample(self, sim: Sim, t_s: float) -> None:
        w = self._writer
        assert w is not None
        t_us = int(t_s * 1e6)
        dt_s = sim.dt_s
        s = sim.state
        R = s.R_world_body[0]
        vel = s.vel_mps[0]
        acc_enu = (vel - self._prev_vel) / dt_s if self._prev_vel is not None else np.zeros(3)
        self._prev_vel = vel.copy()
        # What an accelerometer measures: specific force, in the body frame.
        accel_frd = (R.T @ (acc_enu + _GRAVITY_ENU)) * _FLU_FRD
        gyro_frd = s.omega_rad_s[0] * _FLU_FRD
        dt_us = int(dt_s * 1e6)
        w.write("sensor_combined", t_us, *gyro_frd, dt_us, 0, *accel_frd, dt_us)
        q = quaternion_wxyz(_ENU_TO_NED @ R @ _FRD_TO_FLU)
        w.write("vehicle_attitude", t_us, t_us, *q)
        w.write("vehicle_angular_velocity", t_us, t_us, *gyro_frd)
        ctl = sim.controller
        rate_sp = ctl.rate_sp_rad_s[0] * _FLU_FRD
        max_thrust_n = float(
            4
            * sim.config.airframe.thrust_coeff_n_per_rad2
            * sim.dynamics.max_rotor_speed_rad_s(s)[0] ** 2
        )
        thrust = -float(ctl.thrust_sp_n[0]) / max(max_thrust_n, 1e-9)
        w.write("vehicle_rates_setpoint", t_us, *rate_sp, 0.0, 0.0, thrust)
        motors = ctl.throttle[0]
        w.write("actuator_motors", t_us, t_us, 0, *motors)
        self._steps += 1
        if self._steps % _SLOW_EVERY != 1:
            return
        q_d = quaternion_wxyz(_ENU_TO_NED @ ctl.R_sp[0] @ _FRD_TO_FLU)
        w.write("vehicle_attitude_setpoint", t_us, *q_d, 0.0, 0.0, thrust)
        p = sim.est_pos_m[0] - np.append(sim.scene.start_xy_m, 0.0)
        v = sim.est_vel_mps[0]
        w.write("vehicle_local_position", t_us, p[1], p[0], -p[2], v[1], v[0], -v[2])
        roll, pitch, yaw, thr = sim.sticks[0]
        ch = [
            stick_to_pwm(roll),
            stick_to_pwm(pitch),
            int(round(1000 + 1000 * thr)),
            stick_to_pwm(yaw),
        ]
        w.write("input_rc", t_us, t_us, 8, 100, *ch, 1500, 1000, 1000, 1000)
        armed = bool(sim.commander.armed[0])
        pwm = [1000.0 + 1000.0 * u if armed else 900.0 for u in motors]
        w.write("actuator_outputs", t_us, 4, *pwm)
