"""The twin's parameters as PX4 names them, for ground stations that load parameters
(QGroundControl waits for them). Values mirror the twin's actual configuration; they
are read-only: change the twin through its settings, not PARAM_SET.
"""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.twin.sim import SimConfig

INT32 = mavlink.MAV_PARAM_TYPE_INT32
REAL32 = mavlink.MAV_PARAM_TYPE_REAL32


def px4_params(config: SimConfig, sysid: int = 1) -> dict[str, tuple[float, int]]:
    """name -> (value, MAV_PARAM_TYPE), in a stable order."""
    g, c, af = config.gains, config.commander, config.airframe
    return {
        "SYS_AUTOSTART": (4001, INT32),  # generic quadcopter X
        "MAV_SYS_ID": (sysid, INT32),
        "MAV_TYPE": (mavlink.MAV_TYPE_QUADROTOR, INT32),
        "SYS_HITL": (0, INT32),
        "MPC_XY_VEL_MAX": (g.max_vel_xy_mps, REAL32),
        "MPC_VEL_MANUAL": (g.max_vel_xy_mps, REAL32),
        "MPC_Z_VEL_MAX_UP": (g.max_climb_mps, REAL32),
        "MPC_Z_VEL_MAX_DN": (g.max_descent_mps, REAL32),
        "MPC_LAND_SPEED": (g.land_speed_mps, REAL32),
        "MPC_TKO_SPEED": (g.takeoff_speed_mps, REAL32),
        "MPC_MAN_TILT_MAX": (float(np.degrees(g.max_tilt_rad)), REAL32),
        "MPC_MAN_Y_MAX": (float(np.degrees(g.max_yaw_rate_rad_s)), REAL32),
        "MPC_XY_P": (g.pos_p, REAL32),
        "MPC_Z_P": (g.z_pos_p, REAL32),
        "MC_ROLL_P": (g.att_p[0], REAL32),
        "MC_PITCH_P": (g.att_p[1], REAL32),
        "MC_YAW_P": (g.att_p[2], REAL32),
        "MIS_TAKEOFF_ALT": (c.default_takeoff_alt_m, REAL32),
        "COM_DISARM_LAND": (c.disarm_land_s, REAL32),
        "COM_DISARM_PRFLT": (c.disarm_preflight_s, REAL32),
        "BAT1_N_CELLS": (af.cells, INT32),
        "BAT1_CAPACITY": (af.capacity_ah * 1000.0, REAL32),
        "BAT_CRIT_THR": (c.battery_land_pct / 100.0, REAL32),
        "GPS_1_CONFIG": (201, INT32),  # GPS 1 on the GPS port, as on a Pixhawk 2.4.8
        "SENS_EN_BAROSIM": (0, INT32),
    }


class ParamServer:
    """Answers PARAM_REQUEST_LIST / _READ / _SET with PARAM_VALUE."""

    def __init__(self, mav: mavlink.MAVLink, params: dict[str, tuple[float, int]]) -> None:
        self.mav = mav
        self.names = list(params)
        self.params = params

    def _send(self, index: int) -> None:
        name = self.names[index]
        value, kind = self.params[name]
        self.mav.param_value_send(name.encode(), float(value), kind, len(self.names), index)

    def handle(self, msg) -> str | None:
        """Reply to a parameter message; returns a note for people, if any."""
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            for i in range(len(self.names)):
                self._send(i)
        elif kind == "PARAM_REQUEST_READ":
            name = _name(msg.param_id)
            index = (
                msg.param_index
                if msg.param_index >= 0
                else (self.names.index(name) if name in self.names else -1)
            )
            if 0 <= index < len(self.names):
                self._send(index)
        elif kind == "PARAM_SET":
            name = _name(msg.param_id)
            if name in self.names:
                self._send(self.names.index(name))  # the unchanged value: read-only
                return f"{name} is read-only in the twin"
        return None


def _name(raw) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode(errors="replace")
    return raw.rstrip("\x00")
