"""One simulated world on a sim clock: N vehicles (dynamics + controller + commander +
sensors) in a scene, stepped at a fixed rate, as fast as the CPU allows.

This is the faster-than-real-time API (learning, tests, benchmarks); `twin.runner.Twin`
paces it in real time and puts a MAVLink vehicle and cameras around it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from fpv_station.core.scene import Scene, SceneStart, load_scene
from fpv_station.twin.commander import Commander, CommanderParams, Event
from fpv_station.twin.control import MODE_NAMES, POSCTL, STABILIZED, ControlGains, Controller
from fpv_station.twin.dynamics import CRASH_REASONS, Airframe, BodyState, Dynamics, Wind
from fpv_station.twin.sensors import SensorParams, Sensors

MODE_BY_NAME = {name: code for code, name in MODE_NAMES.items()}
MODE_BY_NAME.update(
    {
        "MANUAL": STABILIZED,
        "POSITION": POSCTL,
        "ALTITUDE": MODE_BY_NAME["ALTCTL"],
        "AUTO.TAKEOFF": MODE_BY_NAME["TAKEOFF"],
        "AUTO.LOITER": MODE_BY_NAME["LOITER"],
        "AUTO.LAND": MODE_BY_NAME["LAND"],
        "AUTO.MISSION": MODE_BY_NAME["MISSION"],
        "AUTO.RTL": MODE_BY_NAME["RTL"],
    }
)

# FLU body / ENU world -> FRD body / NED world, for MAVLink's conventions.
_ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_FRD_TO_FLU = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class SimConfig:
    physics_hz: float = 250.0
    outer_every: int = 5  # position/velocity loop at physics_hz / 5 = 50 Hz
    slow_every: int = 5  # commander, battery, sensor drifts every 5 outer loops = 10 Hz
    seed: int = 0
    # None: the scene's `[wind]` and `[start]` (calm, the pad's centre facing east, unless
    # the scene file says otherwise).
    wind: Wind | None = None
    start: SceneStart | None = None
    sensors: SensorParams = field(default_factory=SensorParams)
    gains: ControlGains = field(default_factory=ControlGains)
    commander: CommanderParams = field(default_factory=CommanderParams)
    airframe: Airframe = field(default_factory=Airframe)
    net_crashes: bool = True


@dataclass(frozen=True)
class Pose:
    """The true pose of one vehicle at sim time `t_s` (ENU world, FLU body)."""

    t_s: float
    pos_enu_m: np.ndarray
    vel_enu_mps: np.ndarray
    R_world_body: np.ndarray
    omega_body_rad_s: np.ndarray

    @property
    def yaw_enu_rad(self) -> float:
        """Heading counter-clockwise from east (0 = facing east, the field's start heading)."""
        return float(np.arctan2(self.R_world_body[1, 0], self.R_world_body[0, 0]))

    @property
    def R_ned_frd(self) -> np.ndarray:
        return _ENU_TO_NED @ self.R_world_body @ _FRD_TO_FLU

    @property
    def euler_ned_rad(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) as MAVLink ATTITUDE reports them; yaw clockwise from north."""
        R = self.R_ned_frd
        return (
            float(np.arctan2(R[2, 1], R[2, 2])),
            float(-np.arcsin(np.clip(R[2, 0], -1, 1))),
            float(np.arctan2(R[1, 0], R[0, 0])),
        )


class Sim:
    def __init__(self, scene: Scene | None = None, config: SimConfig | None = None, n: int = 1):
        self.scene = scene or load_scene()
        self.config = cfg = config or SimConfig()
        self.n = n
        self.dt_s = 1.0 / cfg.physics_hz
        half = (self.scene.field.size_x_m / 2, self.scene.field.size_y_m / 2)
        sw = self.scene.wind
        self.wind = (
            cfg.wind
            if cfg.wind is not None
            else Wind(
                (sw.east_mps, sw.north_mps, 0.0),
                sw.gust_std_mps,
                sw.gust_tau_s,
                sw.turbulence_std_mps,
            )
        )
        self.start = cfg.start if cfg.start is not None else self.scene.start
        self.dynamics = Dynamics(
            airframe=cfg.airframe,
            dt_s=self.dt_s,
            wind=self.wind,
            obstacle_boxes_m=self.scene.obstacle_boxes_m(),
            net_half_extent_m=half if cfg.net_crashes else None,
            net_height_m=self.scene.field.net_height_m,
            seed=cfg.seed,
        )
        self.rng = np.random.default_rng(cfg.seed + 1)
        # Called after every physics step with the sim and its time (the twin's flight
        # log samples its high-rate topics there); None costs nothing.
        self.on_physics_step: Callable[[Sim, float], None] | None = None
        # Its own stream: a random start leaves the sensors' and the wind's draws as they were.
        self._start_rng = np.random.default_rng([cfg.seed, 0x57A27])
        self.reset()

    def reset(self) -> None:
        cfg = self.config
        self.t_s = 0.0
        self.steps = 0
        self.state: BodyState = self.dynamics.initial_state(self.n, *self._start_poses(self.n))
        self.controller = Controller(self.n, cfg.airframe, cfg.gains)
        self.commander = Commander(self.n, cfg.commander)
        self.sensors = Sensors(self.n, self.scene.home, cfg.sensors, self.rng)
        self.sticks = np.tile([0.0, 0.0, 0.0, 0.5], (self.n, 1))  # centred, throttle mid
        self.throttle = np.zeros((self.n, 4))
        self._idle = np.zeros(self.n, bool)
        self.est_pos_m, self.est_vel_mps = self.sensors.estimate(
            self.state.pos_m, self.state.vel_mps
        )
        self.controller.reset(np.ones(self.n, bool), self.est_pos_m, self.state.R_world_body)

    def reset_vehicles(self, mask: np.ndarray) -> None:
        """Put the vehicles in `mask` back on the start pad, disarmed, battery full, sensors
        re-drawn; the others fly on (vectorized environments reset one episode at a time)."""
        idx = np.nonzero(mask)[0]
        if not len(idx):
            return
        fresh = self.dynamics.initial_state(len(idx), *self._start_poses(len(idx)))
        s = self.state
        for name in (
            "pos_m",
            "vel_mps",
            "R_world_body",
            "omega_rad_s",
            "rotor_rad_s",
            "charge_c",
            "voltage_v",
            "current_a",
            "rotor_thrust_n",
            "on_ground",
            "crash",
            "wind_mps",
            "gust_mps",
            "turbulence_mps",
        ):
            getattr(s, name)[idx] = getattr(fresh, name)
        self.dynamics.revive(s)
        self.commander.reset_vehicles(idx)
        self.sensors.redraw(idx)
        self.sticks[idx] = [0.0, 0.0, 0.0, 0.5]
        self.est_pos_m, self.est_vel_mps = self.sensors.estimate(s.pos_m, s.vel_mps)
        self.controller.reset(mask, self.est_pos_m, s.R_world_body)

    def _start_poses(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(xy (n, 2), heading (n,)) of `n` vehicles put on the start pad (`SceneStart`)."""
        pad = self.scene.pads[0]
        if not self.start.random:
            return np.tile(pad.xy_m, (n, 1)), np.zeros(n)
        xy = pad.xy_m + self._start_rng.uniform(-pad.size_m / 2, pad.size_m / 2, (n, 2))
        span = np.radians(self.start.heading_deg)
        return xy, self._start_rng.uniform(-span, span, n)

    # ---- inputs ----
    def set_sticks(
        self, roll: float, pitch: float, yaw: float, throttle: float, i: int = 0
    ) -> None:
        """Normalized sticks: roll/pitch/yaw in [-1, 1], throttle in [0, 1] (0.5 = centred)."""
        self.sticks[i] = np.clip([roll, pitch, yaw, throttle], [-1, -1, -1, 0], [1, 1, 1, 1])

    def arm(self, arm: bool = True, i: int = 0, force: bool = False) -> tuple[bool, str]:
        return self.commander.request_arm(
            i,
            arm,
            bool(self.state.crash[i]),
            self.battery_pct(i),
            self.sensors.has_fix(self.t_s),
            force,
        )

    def set_mode(self, name: str, i: int = 0) -> tuple[bool, str]:
        code = MODE_BY_NAME.get(name.upper())
        if code is None:
            return False, f"unknown mode '{name}'; known: {', '.join(sorted(MODE_BY_NAME))}"
        if code == MODE_BY_NAME["RTL"]:
            return self.return_to_launch(i)
        return self.commander.request_mode(
            i, code, self.est_pos_m[i], self.sensors.has_fix(self.t_s)
        )

    def takeoff(self, alt_m: float | None = None, i: int = 0) -> tuple[bool, str]:
        return self.commander.request_takeoff(i, self.est_pos_m[i], alt_m)

    def land(self, i: int = 0) -> tuple[bool, str]:
        return self.commander.request_land(i, self.est_pos_m[i])

    def return_to_launch(self, i: int = 0) -> tuple[bool, str]:
        """AUTO.RTL to the scene's start pad (the twin's home), landing there."""
        return self.commander.request_return(
            i, self.est_pos_m[i], self.scene.start_xy_m, self.sensors.has_fix(self.t_s)
        )

    # ---- stepping ----
    def step(self, n_steps: int = 1) -> None:
        cfg, s = self.config, self.state
        com, ctl = self.commander, self.controller
        slow_every = cfg.outer_every * cfg.slow_every
        dt_outer, dt_slow = self.dt_s * cfg.outer_every, self.dt_s * slow_every
        # Arming, reset or battery may have changed between calls; then at the outer rate.
        ctl.set_limits(self.dynamics.max_rotor_speed_rad_s(s), com.armed, self._idle)
        steps, end, every = self.steps, self.steps + n_steps, cfg.outer_every
        inner, physics_step = ctl.inner, self.dynamics.step
        while steps < end:
            if steps % slow_every == 0:  # 10 Hz: battery, drifts, commander
                self.dynamics.slow_update(s, dt_slow)
                self.sensors.update(dt_slow)
                fix = np.full(self.n, self.sensors.has_fix(self.t_s))
                com.update(
                    dt_slow,
                    self.sticks,
                    s.on_ground,
                    s.crash,
                    self.est_pos_m,
                    ctl.vel_sp_mps[:, 2],
                    self.battery_pct_all(),
                    fix,
                )
            if steps % every == 0:  # 50 Hz: collisions, estimate, outer loop
                self.dynamics.collisions(s)
                self.sensors.poll_gps(self.t_s, s.pos_m, s.vel_mps)
                self.est_pos_m, self.est_vel_mps = self.sensors.estimate(s.pos_m, s.vel_mps)
                stab = com.mode == STABILIZED
                grounded = com.landed & np.where(
                    stab, self.sticks[:, 3] < 0.15, ctl.vel_sp_mps[:, 2] <= 0.2
                )
                ctl.reset(grounded, self.est_pos_m, s.R_world_body)
                ctl.outer(
                    dt_outer,
                    com.mode,
                    self.sticks,
                    self.est_pos_m,
                    self.est_vel_mps,
                    s.R_world_body,
                    com.target_m,
                )
                self._idle = com.landed & np.where(
                    stab, self.sticks[:, 3] < 0.15, ctl.vel_sp_mps[:, 2] <= 0.2
                )
                ctl.set_limits(self.dynamics.max_rotor_speed_rad_s(s), com.armed, self._idle)
            # Attitude/rate loop and rigid body at the physics rate, up to the next outer tick.
            run = min(every - steps % every, end - steps)
            on_step = self.on_physics_step
            for k in range(run):
                physics_step(s, inner(s.R_world_body, s.omega_rad_s))
                if on_step is not None:
                    on_step(self, (steps + k + 1) * self.dt_s)
            self.throttle = ctl.throttle
            steps += run
            self.steps = steps
            self.t_s = steps * self.dt_s

    def run_for(self, seconds: float) -> None:
        self.step(int(round(seconds / self.dt_s)))

    # ---- outputs ----
    def pose(self, i: int = 0) -> Pose:
        s = self.state
        return Pose(
            self.t_s,
            s.pos_m[i].copy(),
            s.vel_mps[i].copy(),
            s.R_world_body[i].copy(),
            s.omega_rad_s[i].copy(),
        )

    def battery_pct_all(self) -> np.ndarray:
        return 100.0 * self.state.charge_c / (self.config.airframe.capacity_ah * 3600.0)

    def battery_pct(self, i: int = 0) -> float:
        return float(self.battery_pct_all()[i])

    def crash_reason(self, i: int = 0) -> str:
        return CRASH_REASONS[int(self.state.crash[i])]

    def drain_events(self) -> list[Event]:
        events, self.commander.events = self.commander.events, []
        return events
