"""The twin's telemetry as a Pixhawk running PX4 sends it: one encoder per message, from
the sim's state (estimates and sensors where the autopilot would use them, truth only
where PX4 reports its own outputs: modes, sticks, motors).
"""

from __future__ import annotations

import time

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.core.geodesy import enu_to_geodetic
from fpv_station.core.mavlink.px4_modes import px4_custom_mode
from fpv_station.twin.control import ALTCTL, AUTO_TAKEOFF, MODE_NAMES, POSCTL, STABILIZED
from fpv_station.twin.sim import Sim


def stick_to_pwm(x: float) -> int:
    return int(round(1500 + 500 * np.clip(x, -1, 1)))


class Telemetry:
    """Encodes one named message of the sim's vehicle 0 with `mav` (a pymavlink MAVLink)."""

    def __init__(self, mav: mavlink.MAVLink) -> None:
        self.mav = mav
        self.home_alt_m: float | None = None  # PX4's home: set on the ground while armed
        self.home_geo: np.ndarray | None = None  # (lat_deg, lon_deg, alt_m) of that home

    def send(self, name: str, sim: Sim, t_ms: int) -> None:
        getattr(self, "_send_" + name.lower())(sim, t_ms)

    def _send_heartbeat(self, sim: Sim, t_ms: int) -> None:
        com = sim.commander
        mode = int(com.mode[0])
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if mode >= AUTO_TAKEOFF:
            base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        else:
            base |= mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        if com.armed[0]:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if sim.state.crash[0]:
            status = mavlink.MAV_STATE_EMERGENCY
        else:
            status = mavlink.MAV_STATE_ACTIVE if com.armed[0] else mavlink.MAV_STATE_STANDBY
        self.mav.heartbeat_send(
            mavlink.MAV_TYPE_QUADROTOR,
            mavlink.MAV_AUTOPILOT_PX4,
            base,
            px4_custom_mode(MODE_NAMES[mode]),  # the twin's mode names are PX4's
            status,
        )

    def _send_sys_status(self, sim: Sim, t_ms: int) -> None:
        sensors = (
            mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO
            | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
            | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
            | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
            | mavlink.MAV_SYS_STATUS_SENSOR_GPS
            | mavlink.MAV_SYS_STATUS_SENSOR_RC_RECEIVER
            | mavlink.MAV_SYS_STATUS_SENSOR_BATTERY
        )
        health = (
            sensors
            if sim.sensors.has_fix(sim.t_s)
            else sensors & ~mavlink.MAV_SYS_STATUS_SENSOR_GPS
        )
        s = sim.state
        self.mav.sys_status_send(
            sensors,
            sensors,
            health,
            250,
            int(s.voltage_v[0] * 1000),
            int(s.current_a[0] * 100),
            int(sim.battery_pct()),
            0,
            0,
            0,
            0,
            0,
            0,
        )

    def _send_battery_status(self, sim: Sim, t_ms: int) -> None:
        s, af = sim.state, sim.config.airframe
        cell_mv = int(s.voltage_v[0] / af.cells * 1000)
        cells = [cell_mv] * af.cells + [65535] * (10 - af.cells)
        used_mah = int((af.capacity_ah * 3600 - s.charge_c[0]) / 3.6)
        self.mav.battery_status_send(
            0,
            mavlink.MAV_BATTERY_FUNCTION_ALL,
            mavlink.MAV_BATTERY_TYPE_LIPO,
            32767,
            cells,
            int(s.current_a[0] * 100),
            used_mah,
            -1,
            int(sim.battery_pct()),
        )

    def _send_gps_raw_int(self, sim: Sim, t_ms: int) -> None:
        fix = sim.sensors.last_fix[0]
        if fix is None:
            return
        self.mav.gps_raw_int_send(
            int(fix.t_s * 1e6),
            fix.fix_type,
            int(fix.lat_deg * 1e7),
            int(fix.lon_deg * 1e7),
            int(fix.alt_m * 1000),
            min(int(fix.eph_m * 100), 65535),
            min(int(fix.epv_m * 100), 65535),
            int(fix.ground_speed_mps * 100),
            int(fix.course_deg * 100),
            fix.satellites,
        )

    def _send_system_time(self, sim: Sim, t_ms: int) -> None:
        # PX4 knows UTC from its GPS only. The twin's receiver tells the host's clock: it
        # flies on this machine, in real time (a faster-than-real-time gym run has no UTC).
        if sim.sensors.last_fix[0] is None:
            return
        self.mav.system_time_send(int(time.time() * 1e6), t_ms)

    def _fused(self, sim: Sim) -> tuple[np.ndarray, np.ndarray]:
        home = sim.scene.home
        geo = enu_to_geodetic(sim.est_pos_m[0], home.lat_deg, home.lon_deg, home.alt_m)
        return geo, sim.est_vel_mps[0]

    def _send_global_position_int(self, sim: Sim, t_ms: int) -> None:
        if not sim.sensors.has_fix(sim.t_s):
            return
        geo, v = self._fused(sim)
        if self.home_alt_m is None or (sim.commander.armed[0] and sim.commander.landed[0]):
            self.home_alt_m = float(geo[2])  # PX4 sets home at arming, on the ground
            self.home_geo = geo
        yaw = sim.pose().euler_ned_rad[2]
        self.mav.global_position_int_send(
            t_ms,
            int(geo[0] * 1e7),
            int(geo[1] * 1e7),
            int(geo[2] * 1000),
            int((geo[2] - self.home_alt_m) * 1000),
            int(v[1] * 100),
            int(v[0] * 100),
            int(-v[2] * 100),
            int(np.degrees(yaw) % 360 * 100),
        )

    def _send_local_position_ned(self, sim: Sim, t_ms: int) -> None:
        p = sim.est_pos_m[0] - np.append(sim.scene.start_xy_m, 0.0)  # EKF origin: power-on spot
        v = sim.est_vel_mps[0]
        self.mav.local_position_ned_send(t_ms, p[1], p[0], -p[2], v[1], v[0], -v[2])

    def _send_attitude(self, sim: Sim, t_ms: int) -> None:
        pose = sim.pose()
        roll, pitch, yaw = np.array(pose.euler_ned_rad) + sim.sensors.attitude_noise()[0]
        w = pose.omega_body_rad_s * [1, -1, -1]  # FLU -> FRD
        self.mav.attitude_send(t_ms, roll, pitch, (yaw + np.pi) % (2 * np.pi) - np.pi, *w)

    def _send_vfr_hud(self, sim: Sim, t_ms: int) -> None:
        v = sim.est_vel_mps[0]
        air = v - sim.state.wind_mps[0]
        yaw = sim.pose().euler_ned_rad[2]
        thr = int(100 * sim.throttle[0].mean())
        alt = float(sim.sensors.baro_alt_m(sim.state.pos_m)[0])
        self.mav.vfr_hud_send(
            float(np.linalg.norm(air[:2])),
            float(np.hypot(v[0], v[1])),
            int(np.degrees(yaw) % 360),
            thr,
            alt,
            float(v[2]),
        )

    def _send_rc_channels(self, sim: Sim, t_ms: int) -> None:
        roll, pitch, yaw, thr = sim.sticks[0]
        mode_pwm = {STABILIZED: 1100, ALTCTL: 1500, POSCTL: 1900}.get(
            int(sim.commander.mode[0]), 1500
        )
        ch = [
            stick_to_pwm(roll),
            stick_to_pwm(pitch),
            int(round(1000 + 1000 * thr)),
            stick_to_pwm(yaw),
            mode_pwm,
            1000,
            1000,
            1000,
        ] + [65535] * 10
        self.mav.rc_channels_send(t_ms, 8, *ch, 254)

    def _send_servo_output_raw(self, sim: Sim, t_ms: int) -> None:
        armed = bool(sim.commander.armed[0])
        motors = [int(1000 + 1000 * u) if armed else 900 for u in sim.throttle[0]]
        self.mav.servo_output_raw_send((t_ms * 1000) & 0xFFFFFFFF, 0, *motors, 0, 0, 0, 0)

    def _send_autopilot_version(self, sim: Sim, t_ms: int) -> None:
        caps = (
            mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
            | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
        )
        # flight_sw_version 1.14.0 release (0xFF), as PX4 packs it: major.minor.patch.type
        self.mav.autopilot_version_send(
            caps,
            (1 << 24) | (14 << 16) | (0 << 8) | 0xFF,
            0,
            0,
            0,
            [0] * 8,
            [0] * 8,
            [0] * 8,
            0,
            0,
            0x7717,
        )

    def _send_extended_sys_state(self, sim: Sim, t_ms: int) -> None:
        self.mav.extended_sys_state_send(
            mavlink.MAV_VTOL_STATE_UNDEFINED, sim.commander.landed_state(0)
        )

    def _send_home_position(self, sim: Sim, t_ms: int) -> None:
        if self.home_geo is None:
            return  # no fix yet: PX4 has no home either
        lat, lon, alt = self.home_geo
        self.mav.home_position_send(
            int(lat * 1e7),
            int(lon * 1e7),
            int(alt * 1000),
            0.0,
            0.0,
            0.0,
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            0.0,
            0.0,
        )
