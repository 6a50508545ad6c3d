"""A scripted pilot: flies the scene's tasks through the same sticks a human gives in
Position mode (arm by stick gesture, throttle for climb, pitch/roll for velocity, throttle
down to land), so recordings of it look like recordings of a person.

    pilot = Pilot(task_plan(scene, 2))
    sticks = pilot.update(observation)     # call at ~50 Hz, send the sticks
    fly(sim, pilot)                        # or fly an in-process Sim to the end

Observations are in the scene's world frame (ENU, m). A plan is a list of legs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fpv_station.core.scene import Scene

DEADBAND = 0.1  # the controller's stick deadband; commands start just outside it
# A pilot told to climb to 4 m climbs until the display reads 4 m: aim a little above the
# target so that it is crossed at a steady climb rate, not approached asymptotically
# from below (the paper's hover window starts when the altitude first reaches 4 m).
CLIMB_MARGIN_M = 0.2


@dataclass(frozen=True)
class Leg:
    kind: str  # "arm", "climb", "hold", "goto", "land"
    xy_m: tuple[float, float] | None = None
    alt_m: float = 0.0
    seconds: float = 0.0
    tolerance_m: float = 0.5


@dataclass
class Observation:
    t_s: float
    pos_enu_m: np.ndarray
    vel_enu_mps: np.ndarray
    yaw_enu_rad: float  # heading, counter-clockwise from east
    armed: bool


@dataclass
class Pilot:
    legs: list[Leg]
    cruise_mps: float = 1.5
    max_vel_xy_mps: float = 5.0  # the vehicle's stick full-scale velocity
    max_climb_mps: float = 3.0
    max_descent_mps: float = 1.5
    descent_mps: float = 0.5  # "descend slowly"
    leg: int = 0
    done: bool = False
    _leg_t0: float | None = None
    _hold_xy: np.ndarray | None = None
    _hold_alt: float = 0.0
    log: list[str] = field(default_factory=list)

    def _next(self, obs: Observation) -> None:
        self.log.append(f"{obs.t_s:7.2f} s: finished {self.legs[self.leg].kind}")
        self.leg += 1
        self._leg_t0 = None
        self.done = self.leg >= len(self.legs)

    def update(self, obs: Observation) -> tuple[float, float, float, float]:
        """Sticks (roll, pitch, yaw, throttle) for this observation."""
        if self.done:
            return (0.0, 0.0, 0.0, 0.0 if not obs.armed else 0.5)
        leg = self.legs[self.leg]
        hold_xy = self._hold_xy
        if self._leg_t0 is None or hold_xy is None:  # a leg starts (both are set together)
            self._leg_t0 = obs.t_s
            hold_xy = obs.pos_enu_m[:2].copy() if leg.xy_m is None else np.array(leg.xy_m)
            self._hold_xy = hold_xy
            self._hold_alt = float(obs.pos_enu_m[2])
        elapsed = obs.t_s - self._leg_t0
        z = float(obs.pos_enu_m[2])
        if leg.kind == "arm":
            if obs.armed:
                self._next(obs)
                return (0.0, 0.0, 0.0, 0.5)
            return (0.0, 0.0, 1.0, 0.0)  # the gesture: throttle down, yaw right
        if leg.kind == "climb":
            if z >= leg.alt_m:
                self._next(obs)
            return self._fly(obs, hold_xy, leg.alt_m + CLIMB_MARGIN_M)
        if leg.kind == "hold":
            if elapsed >= leg.seconds:
                self._next(obs)
            return self._fly(obs, hold_xy, leg.alt_m or self._hold_alt)
        if leg.kind == "goto":
            d = np.hypot(*(np.array(leg.xy_m) - obs.pos_enu_m[:2]))
            if d < leg.tolerance_m:
                self._next(obs)
            return self._fly(obs, np.array(leg.xy_m), leg.alt_m, cruise=True)
        if leg.kind == "land":
            if not obs.armed:  # auto-disarm after the landing: the flight is over
                self._next(obs)
                return (0.0, 0.0, 0.0, 0.0)
            roll, pitch, _, _ = self._fly(obs, hold_xy, z)
            if z < 0.05 and abs(obs.vel_enu_mps[2]) < 0.1:
                return (0.0, 0.0, 0.0, 0.0)  # on the ground: throttle down, wait
            return (roll, pitch, 0.0, self._throttle(-self.descent_mps))
        raise ValueError(f"unknown leg kind '{leg.kind}'")

    def _fly(self, obs: Observation, xy: np.ndarray, alt: float, cruise: bool = False):
        err = xy - obs.pos_enu_m[:2]
        dist = float(np.hypot(*err))
        speed = min(self.cruise_mps if cruise else 1.0, 0.8 * dist)
        v_world = err / dist * speed if dist > 1e-6 else np.zeros(2)
        c, s = np.cos(obs.yaw_enu_rad), np.sin(obs.yaw_enu_rad)
        forward = v_world[0] * c + v_world[1] * s
        right = v_world[0] * s - v_world[1] * c
        climb = float(
            np.clip(1.0 * (alt - obs.pos_enu_m[2]), -self.max_descent_mps, self.max_climb_mps)
        )
        return (
            _stick(right / self.max_vel_xy_mps),
            _stick(forward / self.max_vel_xy_mps),
            0.0,
            self._throttle(climb),
        )

    def _throttle(self, climb_mps: float) -> float:
        scale = self.max_climb_mps if climb_mps > 0 else self.max_descent_mps
        return 0.5 + 0.5 * _stick(climb_mps / scale)


def _stick(command: float) -> float:
    """Normalized command in [-1, 1] -> stick position just outside the deadband."""
    c = float(np.clip(command, -1.0, 1.0))
    if abs(c) < 1e-3:
        return 0.0
    return float(np.sign(c) * (DEADBAND + (1 - DEADBAND) * abs(c)))


def task_plan(scene: Scene, task_id: int) -> list[Leg]:
    """The legs of one of the scene's tasks (1 hover, 2 A to B, 3 obstacle circle, 4 figure 8)."""
    task = scene.task(task_id)
    end = scene.pad(task.end_pad)
    tallest = max((o.height_m for o in scene.obstacles), default=0.0)
    cruise_alt = max(task.altitude_m, tallest + 1.0)  # "above 3 m" over 3 m obstacles
    legs = [Leg("arm"), Leg("climb", alt_m=task.altitude_m if task_id == 1 else cruise_alt)]
    if task_id == 1:
        legs += [Leg("hold", alt_m=task.altitude_m, seconds=task.hold_s or 10.0), Leg("land")]
        return legs
    if task_id == 3 and task.circle_obstacle:
        o = scene.obstacle(task.circle_obstacle)
        r = 3.0
        angles = np.pi + np.linspace(0, 2 * np.pi, 13)  # start on the approach side
        legs += [
            Leg("goto", (o.x_m + r * np.cos(a), o.y_m + r * np.sin(a)), cruise_alt, tolerance_m=0.7)
            for a in angles
        ]
    if task_id == 4:
        xs = sorted(o.x_m for o in scene.obstacles)[:2] or [-7.0, 7.0]
        cx, half = (xs[0] + xs[-1]) / 2, (xs[-1] - xs[0]) / 2 + 3.0
        t = np.linspace(0, 2 * np.pi, 25)[1:]
        # Lemniscate of Gerono through the middle: lobes around each obstacle.
        pts = [(cx - half * np.sin(a), 0.6 * half * np.sin(a) * np.cos(a)) for a in t]
        legs += [Leg("goto", (cx, 0.0), cruise_alt, tolerance_m=0.7)]
        legs += [Leg("goto", p, cruise_alt, tolerance_m=0.8) for p in pts]
    legs += [
        Leg("goto", (end.x_m, end.y_m), cruise_alt, tolerance_m=0.3),
        Leg("hold", alt_m=cruise_alt, seconds=2.0),
        Leg("land"),
    ]
    return legs


def fly(
    sim, pilot: Pilot, timeout_s: float = 600.0, rate_hz: float = 50.0, i: int = 0
) -> np.ndarray:
    """Fly an in-process `twin.sim.Sim` with `pilot` until its plan ends, a crash, or
    `timeout_s`; returns the true track (K, 4) of t_s, x, y, z."""
    n = max(1, int(round(1.0 / (rate_hz * sim.dt_s))))
    track = []
    while not pilot.done and sim.t_s < timeout_s and not sim.state.crash[i]:
        pose = sim.pose(i)
        yaw = float(np.arctan2(pose.R_world_body[1, 0], pose.R_world_body[0, 0]))
        obs = Observation(
            sim.t_s, pose.pos_enu_m, pose.vel_enu_mps, yaw, bool(sim.commander.armed[i])
        )
        sim.set_sticks(*pilot.update(obs), i=i)
        sim.step(n)
        track.append((sim.t_s, *pose.pos_enu_m))
    return np.array(track)


def fly_twin(
    twin, pilot: Pilot, timeout_s: float = 600.0, rate_hz: float = 50.0, stop=None
) -> np.ndarray:
    """Fly a `twin.runner.Twin` with `pilot`; returns the true track (K, 4) of t_s, x, y, z.

    With the twin's real-time thread running (as in the station), the sticks go in at
    `rate_hz` of sim time, paced by the wall clock, and everything else (MAVLink,
    cameras, recorder) sees a normal flight. Without it, the twin is stepped faster than
    real time (`Twin.step_for`, MAVLink still polled every tick). `stop` (a
    threading.Event) ends the flight early.
    """
    import time

    period_s = 1.0 / rate_hz
    t0 = twin.pose().t_s
    track = []
    while not pilot.done and not (stop is not None and stop.is_set()):
        with twin.lock:
            sim = twin.sim
            pose = sim.pose()
            armed, crashed = bool(sim.commander.armed[0]), bool(sim.state.crash[0])
        if crashed or pose.t_s - t0 > timeout_s:
            break
        yaw = float(np.arctan2(pose.R_world_body[1, 0], pose.R_world_body[0, 0]))
        twin.set_sticks(
            *pilot.update(Observation(pose.t_s, pose.pos_enu_m, pose.vel_enu_mps, yaw, armed))
        )
        track.append((pose.t_s, *pose.pos_enu_m))
        if twin.running:
            time.sleep(period_s / twin.realtime_factor)
        else:
            twin.step_for(period_s)
    return np.array(track)
