"""PX4-like commander for N vehicles: arming, modes, land detection, auto-disarm, failsafes.

Arming: by command (MAV_CMD_COMPONENT_ARM_DISARM) or the stick gesture (throttle down and
yaw right for 1 s; throttle down and yaw left for 1 s disarms on the ground). Arming is
refused after a crash, with an empty battery, or in Position mode without a GPS fix.
Land detector: ground contact with no climb demand for 0.5 s. Auto-disarm 2 s after
landing (COM_DISARM_LAND) and 10 s after arming without a take-off (COM_DISARM_PRFLT).
Battery below 10 % in the air switches to LAND; a crash disarms. Messages for people
(STATUSTEXT) collect in `events`.

Return (AUTO.RTL, `request_return`): climb to RTL_MIN_ALT_M if lower, fly home, then
descend there and land, all in one mode, as PX4 reports its Return mode from the climb to
the touchdown; a pilot's mode change ends it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fpv_station.twin.control import (
    ALTCTL,
    AUTO_LAND,
    AUTO_LOITER,
    AUTO_MISSION,
    AUTO_RTL,
    AUTO_TAKEOFF,
    MODE_NAMES,
    POSCTL,
    STABILIZED,
)
from fpv_station.twin.dynamics import CRASH_REASONS

ACCEPT_RADIUS_M = 1.0  # arrived over a place (PX4 NAV_ACC_RAD is 2 m; a netted field needs less)
RTL_MIN_ALT_M = 3.0  # above the field's 3 m obstacles on the way home
LAND_LEAD_M = 0.7  # the descent target's lead below the vehicle: 0.7 m/s, PX4's MPC_LAND_SPEED

LANDED_STATE_ON_GROUND, LANDED_STATE_IN_AIR, LANDED_STATE_TAKEOFF, LANDED_STATE_LANDING = (
    1,
    2,
    3,
    4,
)  # MAV_LANDED_STATE


@dataclass(frozen=True)
class CommanderParams:
    gesture_s: float = 1.0
    land_detect_s: float = 0.5
    disarm_land_s: float = 2.0
    disarm_preflight_s: float = 10.0
    battery_land_pct: float = 10.0
    default_takeoff_alt_m: float = 2.5  # MIS_TAKEOFF_ALT


@dataclass
class Event:
    vehicle: int
    severity: int  # MAV_SEVERITY: 2 critical, 4 warning, 6 info
    text: str


class Commander:
    def __init__(
        self, n: int, params: CommanderParams | None = None, initial_mode: int = POSCTL
    ) -> None:
        self.p = params or CommanderParams()
        self.n = n
        self.armed = np.zeros(n, bool)
        self.mode = np.full(n, initial_mode, int)
        self.landed = np.ones(n, bool)
        self.target_m = np.zeros((n, 3))  # AUTO modes' position setpoint (ENU)
        self._gesture_s = np.zeros(n)
        self._land_s = np.zeros(n)
        self._since_arm_s = np.zeros(n)
        self._ever_flew = np.zeros(n, bool)
        self._crash_reported = np.zeros(n, bool)
        self._battery_failsafe = np.zeros(n, bool)
        self._rtl_landing = np.zeros(n, bool)  # AUTO.RTL: home reached, descending
        self.events: list[Event] = []

    def reset_vehicles(self, idx: np.ndarray) -> None:
        self.armed[idx] = False
        self.mode[idx] = POSCTL
        self.landed[idx] = True
        self.target_m[idx] = 0.0
        for arr in (self._gesture_s, self._land_s, self._since_arm_s):
            arr[idx] = 0.0
        for arr in (
            self._ever_flew,
            self._crash_reported,
            self._battery_failsafe,
            self._rtl_landing,
        ):
            arr[idx] = False

    def mode_name(self, i: int = 0) -> str:
        return MODE_NAMES[int(self.mode[i])]

    def landed_state(self, i: int = 0) -> int:
        if self.landed[i]:
            return LANDED_STATE_ON_GROUND
        if self.mode[i] == AUTO_TAKEOFF:
            return LANDED_STATE_TAKEOFF
        if self.mode[i] == AUTO_LAND or (self.mode[i] == AUTO_RTL and self._rtl_landing[i]):
            return LANDED_STATE_LANDING
        return LANDED_STATE_IN_AIR

    # ---- requests (from MAVLink commands or the API); each returns (accepted, reason) ----
    def request_arm(
        self,
        i: int,
        arm: bool,
        crashed: bool,
        battery_pct: float,
        gps_fix: bool,
        force: bool = False,
    ) -> tuple[bool, str]:
        if not arm:
            if not self.armed[i]:
                return True, "already disarmed"
            if not self.landed[i] and not force:
                return False, "disarm refused: in the air (use force)"
            self._set_armed(i, False, "disarmed by command")
            return True, ""
        if self.armed[i]:
            return True, "already armed"
        if crashed:
            return False, "arming refused: the vehicle has crashed (reset the twin)"
        if battery_pct <= self.p.battery_land_pct:
            return False, "arming refused: battery low"
        if self.mode[i] == POSCTL and not gps_fix:
            return False, "arming refused: Position mode needs a GPS fix"
        if not self.landed[i]:
            return False, "arming refused: not on the ground"
        self._set_armed(i, True, "armed")
        return True, ""

    def request_mode(self, i: int, mode: int, pos_m: np.ndarray, gps_fix: bool) -> tuple[bool, str]:
        if mode not in MODE_NAMES:
            return False, f"unsupported mode {mode}"
        if mode in (POSCTL, AUTO_TAKEOFF, AUTO_LOITER, AUTO_LAND, AUTO_MISSION) and not gps_fix:
            return False, f"{MODE_NAMES[mode]} refused: no GPS fix"
        if mode == AUTO_TAKEOFF:
            return self.request_takeoff(i, pos_m, None)
        if mode == AUTO_RTL:
            return False, "RTL needs home: request_return"
        if mode in (AUTO_LOITER, AUTO_LAND, AUTO_MISSION):  # hold until told where to go
            self.target_m[i] = pos_m
        self._switch(i, mode)
        return True, ""

    def request_takeoff(self, i: int, pos_m: np.ndarray, alt_m: float | None) -> tuple[bool, str]:
        """Climb to `alt_m` above the ground (PX4 takes AMSL in the command; the vehicle
        converts) and loiter. Needs the vehicle armed or arms it if landed."""
        if not self.armed[i]:
            return False, "takeoff refused: disarmed"
        alt = self.p.default_takeoff_alt_m if alt_m is None or not np.isfinite(alt_m) else alt_m
        self.target_m[i] = [pos_m[0], pos_m[1], max(alt, 0.5)]
        self._switch(i, AUTO_TAKEOFF)
        return True, ""

    def request_return(
        self, i: int, pos_m: np.ndarray, home_xy_m: np.ndarray, gps_fix: bool
    ) -> tuple[bool, str]:
        """AUTO.RTL: home at RTL_MIN_ALT_M or the current height if higher, then land."""
        if not self.armed[i] or self.landed[i]:
            return False, "return refused: not flying"
        if not gps_fix:
            return False, "RTL refused: no GPS fix"
        self.target_m[i] = [home_xy_m[0], home_xy_m[1], max(pos_m[2], RTL_MIN_ALT_M)]
        self._rtl_landing[i] = False
        self._switch(i, AUTO_RTL)
        return True, ""

    def request_land(self, i: int, pos_m: np.ndarray) -> tuple[bool, str]:
        self.target_m[i] = pos_m
        self._switch(i, AUTO_LAND)
        return True, ""

    # ---- periodic update (outer-loop rate) ----
    def update(
        self,
        dt: float,
        sticks: np.ndarray,
        on_ground: np.ndarray,
        crash: np.ndarray,
        pos_m: np.ndarray,
        vel_sp_z: np.ndarray,
        battery_pct: np.ndarray,
        gps_fix: np.ndarray,
    ) -> None:
        p = self.p
        low = sticks[:, 3] < 0.1
        gesture = low & ((sticks[:, 2] > 0.9) & ~self.armed | (sticks[:, 2] < -0.9) & self.armed)
        self._gesture_s = np.where(gesture, self._gesture_s + dt, 0.0)
        for i in np.nonzero(self._gesture_s >= p.gesture_s)[0]:
            self._gesture_s[i] = -1e9  # one action per gesture: wait for the sticks to move
            if self.armed[i]:
                if self.landed[i]:
                    self._set_armed(int(i), False, "disarmed by stick gesture")
            else:
                ok, why = self.request_arm(
                    int(i), True, bool(crash[i]), float(battery_pct[i]), bool(gps_fix[i])
                )
                if not ok:
                    self.events.append(Event(int(i), 4, why))

        # Land detector: contact and no climb demand; take-off: leaving the ground.
        wants_up = vel_sp_z > 0.2
        stab = self.mode == STABILIZED
        wants_up = np.where(stab, sticks[:, 3] > 0.15, wants_up)
        calm = on_ground & ~wants_up
        self._land_s = np.where(calm, self._land_s + dt, 0.0)
        took_off = self.landed & self.armed & ~on_ground
        self._ever_flew |= took_off
        self.landed = np.where(took_off, False, self.landed)
        touched = ~self.landed & (self._land_s >= p.land_detect_s)
        for i in np.nonzero(touched)[0]:
            self.events.append(Event(int(i), 6, "landing detected"))
        self.landed |= touched
        self.landed |= ~self.armed & on_ground

        # AUTO transitions.
        reached = (self.mode == AUTO_TAKEOFF) & (pos_m[:, 2] > self.target_m[:, 2] - 0.2)
        for i in np.nonzero(reached)[0]:
            # Hold here, at the take-off altitude (not the 0.2 m short of it we are at).
            self.target_m[i, :2] = pos_m[i, :2]
            self._switch(int(i), AUTO_LOITER)
        rtl = self.mode == AUTO_RTL
        if rtl.any():  # home reached: descend there (the z loop turns the lead into a rate)
            off = pos_m[:, :2] - self.target_m[:, :2]
            home = np.hypot(off[:, 0], off[:, 1]) <= ACCEPT_RADIUS_M
            self._rtl_landing |= rtl & home
            landing = rtl & self._rtl_landing
            self.target_m[:, 2] = np.where(landing, pos_m[:, 2] - LAND_LEAD_M, self.target_m[:, 2])

        # Auto-disarm and failsafes.
        self._since_arm_s = np.where(self.armed, self._since_arm_s + dt, 0.0)
        landed_long = self.armed & self.landed & (self._land_s >= p.disarm_land_s) & self._ever_flew
        never_flew = (
            self.armed
            & self.landed
            & ~self._ever_flew
            & (self._since_arm_s >= p.disarm_preflight_s)
        )
        for i in np.nonzero(landed_long | never_flew)[0]:
            self._set_armed(
                int(i),
                False,
                "auto-disarmed after landing" if landed_long[i] else "auto-disarmed: no take-off",
            )
        low_batt = (
            self.armed & ~self.landed & (battery_pct < p.battery_land_pct) & ~self._battery_failsafe
        )
        for i in np.nonzero(low_batt)[0]:
            self._battery_failsafe[i] = True
            self.events.append(Event(int(i), 2, "battery critical: landing"))
            self.request_land(int(i), pos_m[i])
        crashed = (crash != 0) & ~self._crash_reported
        for i in np.nonzero(crashed)[0]:
            self._crash_reported[i] = True
            self.events.append(Event(int(i), 2, f"CRASH: {CRASH_REASONS[int(crash[i])]}"))
            if self.armed[i]:
                self._set_armed(int(i), False, "disarmed after crash")

    def _set_armed(self, i: int, armed: bool, text: str) -> None:
        self.armed[i] = armed
        self._since_arm_s[i] = 0.0
        self._land_s[i] = 0.0
        if armed:
            self._ever_flew[i] = False
        elif self.mode[i] in (AUTO_TAKEOFF, AUTO_LOITER):
            self.mode[i] = POSCTL  # PX4 drops out of AUTO hold when disarmed on the ground
        self.events.append(Event(i, 6 if armed or "auto" in text else 4, text))

    def _switch(self, i: int, mode: int) -> None:
        if self.mode[i] != mode:
            self.mode[i] = mode
            self.events.append(Event(i, 6, f"mode {MODE_NAMES[mode]}"))


__all__ = [
    "Commander",
    "CommanderParams",
    "Event",
    "ALTCTL",
    "POSCTL",
    "STABILIZED",
    "AUTO_TAKEOFF",
    "AUTO_LOITER",
    "AUTO_LAND",
    "AUTO_MISSION",
    "AUTO_RTL",
]
