"""The twin's mission: the items a ground station uploaded, and flying them in AUTO.MISSION
as PX4 does (take-off, waypoints, timed and unlimited loiters, return, land).

Positions arrive as WGS-84 latitude/longitude with an altitude in the item's frame:
relative to home (MAV_FRAME_GLOBAL_RELATIVE_ALT*, and terrain frames, the field being
flat) or above mean sea level (MAV_FRAME_GLOBAL*). They become targets in the sim's ENU
world, whose origin is the scene's home at ground level.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.core.geodesy import geodetic_to_enu
from fpv_station.twin.commander import ACCEPT_RADIUS_M, LAND_LEAD_M, RTL_MIN_ALT_M
from fpv_station.twin.control import AUTO_LOITER, AUTO_MISSION
from fpv_station.twin.sim import Sim

RELATIVE_FRAMES = frozenset(
    {
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
        mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
        mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
    }
)
AMSL_FRAMES = frozenset({mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT})
FRAMES = RELATIVE_FRAMES | AMSL_FRAMES | {mavlink.MAV_FRAME_MISSION}
COMMANDS = frozenset(
    {
        mavlink.MAV_CMD_NAV_WAYPOINT,
        mavlink.MAV_CMD_NAV_LOITER_UNLIM,
        mavlink.MAV_CMD_NAV_LOITER_TIME,
        mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH,
        mavlink.MAV_CMD_NAV_LAND,
        mavlink.MAV_CMD_NAV_TAKEOFF,
    }
)
ACCEPT_ALT_M = 0.5


@dataclass(frozen=True)
class MissionItem:
    """One MISSION_ITEM(_INT), with latitude/longitude in degrees whichever it came as."""

    seq: int
    frame: int
    command: int
    autocontinue: bool
    param1: float
    param2: float
    param3: float
    param4: float
    lat_deg: float
    lon_deg: float
    alt_m: float  # in `frame`

    @staticmethod
    def from_message(msg: mavlink.MAVLink_message) -> MissionItem:
        scale = 1e-7 if msg.get_type() == "MISSION_ITEM_INT" else 1.0
        return MissionItem(
            seq=msg.seq,
            frame=msg.frame,
            command=msg.command,
            autocontinue=bool(msg.autocontinue),
            param1=msg.param1,
            param2=msg.param2,
            param3=msg.param3,
            param4=msg.param4,
            lat_deg=msg.x * scale,
            lon_deg=msg.y * scale,
            alt_m=msg.z,
        )

    def has_position(self) -> bool:
        return self.frame != mavlink.MAV_FRAME_MISSION and not (
            self.lat_deg == 0 and self.lon_deg == 0
        )

    def problem(self) -> int | None:
        """MAV_MISSION_RESULT for an item the twin cannot fly, None if it can."""
        if self.command not in COMMANDS:
            return mavlink.MAV_MISSION_UNSUPPORTED
        if self.frame not in FRAMES:
            return mavlink.MAV_MISSION_UNSUPPORTED_FRAME
        if self.frame in AMSL_FRAMES | RELATIVE_FRAMES and not math.isfinite(self.alt_m):
            return mavlink.MAV_MISSION_INVALID_PARAM7
        return None


def up_m(sim: Sim, alt_m: float, frame: int, home_alt_m: float) -> float:
    """An altitude in `frame` as the height in the sim's world (above the scene's home)."""
    base = home_alt_m if frame in RELATIVE_FRAMES else 0.0
    return alt_m + base - sim.scene.home.alt_m


def target_enu(
    sim: Sim, lat_deg: float, lon_deg: float, alt_m: float, frame: int, home_alt_m: float
) -> np.ndarray:
    """A global position in `frame` as an ENU target in the sim's world (m)."""
    home = sim.scene.home
    e, n, _ = geodetic_to_enu(lat_deg, lon_deg, home.alt_m, *sim.scene.home_llh)
    return np.array([float(e), float(n), up_m(sim, alt_m, frame, home_alt_m)])


class MissionRunner:
    """Flies the mission while the commander is in AUTO.MISSION and armed.

    `update` runs after the vehicle has handled its inputs, every twin tick: it points the
    commander's target at the current item and moves on when the item is reached.
    `reached(seq)` and `current_changed(seq)` tell the ground station (MISSION_ITEM_REACHED,
    MISSION_CURRENT)."""

    def __init__(
        self,
        reached: Callable[[int], None],
        current_changed: Callable[[int], None],
        say: Callable[[str], None],
    ) -> None:
        self.items: list[MissionItem] = []
        self.current = 0
        self._reached = reached
        self._current_changed = current_changed
        self._say = say
        self._entered_s: float | None = None  # when the current item was started
        self._arrived_s: float | None = None  # when its position was reached (holds)
        self._target: np.ndarray | None = None
        self._landing = False
        self.finished = False  # flown to the end: nothing more until disarmed

    def load(self, items: list[MissionItem]) -> None:
        self.items = list(items)
        self._start_item(0)

    def set_current(self, seq: int) -> bool:
        """Make item `seq` the next to fly; False if there is no such item."""
        if not 0 <= seq < len(self.items):
            return False
        self._start_item(seq)
        return True

    def _start_item(self, seq: int) -> None:
        self.current = seq
        self._entered_s = self._arrived_s = None
        self._target = None
        self._landing = False
        self._current_changed(seq)

    def update(self, sim: Sim, now_s: float, home_alt_m: float) -> None:
        com = sim.commander
        if not com.armed[0]:
            self._entered_s = self._arrived_s = None  # arming again starts the item afresh
            self._landing = self.finished = False
            return
        if com.mode[0] != AUTO_MISSION or not self.items or self.finished:
            return
        item = self.items[self.current]
        pos = sim.est_pos_m[0]
        if self._entered_s is None:
            self._entered_s = now_s
            self._target = self._first_target(sim, item, pos, home_alt_m)
        target = self._target
        assert target is not None
        com.target_m[0] = target
        cmd = item.command
        if cmd in (mavlink.MAV_CMD_NAV_LAND, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH):
            if not self._landing and _dist_xy(pos, target) <= ACCEPT_RADIUS_M:
                self._landing = True
            if self._landing:  # the z loop (gain 1/s) turns the lead into a descent rate
                com.target_m[0, 2] = pos[2] - LAND_LEAD_M
                if com.landed[0]:
                    self._reached(item.seq)
                    self._say("mission finished, landed")
                    self.finished = True
                    self._start_item(0)  # PX4 rewinds a finished mission for the next flight
            return
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            arrived = pos[2] >= target[2] - ACCEPT_ALT_M
        else:
            radius = (
                item.param2
                if cmd == mavlink.MAV_CMD_NAV_WAYPOINT and item.param2 > 0
                else ACCEPT_RADIUS_M
            )
            arrived = _dist_xy(pos, target) <= radius and abs(pos[2] - target[2]) <= ACCEPT_ALT_M
        if self._arrived_s is None:
            if not arrived:
                return
            self._arrived_s = now_s
            self._reached(item.seq)
        if cmd == mavlink.MAV_CMD_NAV_LOITER_UNLIM:
            return
        hold_s = (
            item.param1
            if cmd in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_TIME)
            else 0.0
        )
        if now_s - self._arrived_s >= max(hold_s, 0.0) and item.autocontinue:
            if self.current + 1 < len(self.items):
                self.set_current(self.current + 1)
            else:  # PX4 holds where the last item left it
                self.finished = True
                self._say("mission finished, loitering")
                com.request_mode(0, AUTO_LOITER, pos, True)

    def _first_target(
        self, sim: Sim, item: MissionItem, pos: np.ndarray, home_alt_m: float
    ) -> np.ndarray:
        cmd = item.command
        if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            home = np.append(sim.scene.start_xy_m, 0.0)
            return np.array([home[0], home[1], max(pos[2], RTL_MIN_ALT_M)])
        if item.has_position():
            t = target_enu(sim, item.lat_deg, item.lon_deg, item.alt_m, item.frame, home_alt_m)
        else:
            t = pos.copy()
            if item.frame in RELATIVE_FRAMES | AMSL_FRAMES:
                t[2] = up_m(sim, item.alt_m, item.frame, home_alt_m)
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            t[:2] = pos[:2]  # a multicopter climbs straight up where it stands
            t[2] = max(t[2], 0.5)
        elif cmd == mavlink.MAV_CMD_NAV_LAND:
            t[2] = pos[2]  # fly there at the current height, then descend
        return t


def _dist_xy(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.hypot(a[0] - b[0], a[1] - b[1]))
