"""A Gymnasium environment on the twin, as the paper proposes for imitation and
reinforcement learning: the agent gives the same four sticks a pilot gives in Position
mode; the twin is stepped faster than real time.

    env = TwinEnv(task=2)                     # fly from the start pad to the landing pad
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

## Action Space
`Box(-1, 1, (4,), float32)`: roll (right +), pitch (forward +), yaw (clockwise +),
throttle (-1 full descent, 0 centred = hold altitude, +1 full climb), held for one
control period (`1 / control_hz`, default 0.1 s).

## Observation Space
`Box(-1e4, 1e4, (18,), float32)`: position relative to the target (3, ENU m), velocity
(3, ENU m/s), roll, pitch (rad), sin and cos of the heading, body rates (3, rad/s),
battery fraction, armed, on the ground, horizontal distance and height above the target.
With `cameras=("bottom",)` (or "front") the observation is a Dict of that vector
("state") and the camera images, (H, W, 3) uint8 RGB at `image_size`.

## Rewards
Progress: the decrease of the distance to the target each step; -0.01 per step for
time; +10 on landing within 0.5 m of the target pad (task 1: holding 4 m over the start
pad for 10 s, then landing on it); -10 on a crash.

## Starting State
On the task's start pad, armed, Position mode, sensors warmed up (GPS fix). Sensor noise,
drift, gusts and turbulence come from the episode's seed.

## Wind and start (options)
`TwinEnv(wind=..., start=...)`, or per episode `reset(options={"wind": ..., "start": ...})`:
`wind` a `twin.dynamics.Wind` or a mapping of its fields (`mean_enu_mps`, `gust_std_mps`,
`gust_tau_s`, `turbulence_std_mps`); `start` a `core.scene.SceneStart` or a mapping
(`random`, `heading_deg`): with `random`, the vehicle stands anywhere on the start pad
facing within `heading_deg` of east, drawn from the episode's seed. Unset: the scene's
`[wind]` and `[start]` (the default field: calm, the pad's centre facing east).

## Episode End
Terminated: crash, or landed (disarmed after touchdown). Truncated: `max_episode_s`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from fpv_station.core.scene import Scene, SceneStart, Task, load_scene
from fpv_station.twin.dynamics import Wind
from fpv_station.twin.sim import Sim, SimConfig

if TYPE_CHECKING:  # imported when a camera is first rendered (OpenCV)
    from fpv_station.twin.render import Renderer

# What each element of the state vector is; exporters name dataset features with these.
STATE_NAMES: tuple[str, ...] = (
    "x_to_target_m",
    "y_to_target_m",
    "z_to_target_m",
    "vel_east_mps",
    "vel_north_mps",
    "vel_up_mps",
    "roll_rad",
    "pitch_rad",
    "sin_heading",
    "cos_heading",
    "rate_roll_rad_s",
    "rate_pitch_rad_s",
    "rate_yaw_rad_s",
    "battery_fraction",
    "armed",
    "on_ground",
    "horizontal_distance_m",
    "height_above_target_m",
)
STATE_SIZE = len(STATE_NAMES)
# Registered with Gymnasium on import: `gym.make(ENV_ID, task=1)`; datasets (Minari) store
# this id and entry point so the env can be rebuilt from them.
ENV_ID = "fpv_station/TwinEnv-v0"
ACTION_NAMES: tuple[str, ...] = ("roll", "pitch", "yaw", "throttle")


class EpisodeTwin:
    """The twin of an environment's episode, made by its reset()."""

    _sim: Sim | None = None

    @property
    def sim(self) -> Sim:
        """The episode's twin; RuntimeError before the first reset()."""
        if self._sim is None:
            raise RuntimeError("call reset() before step()")
        return self._sim


class TwinEnv(EpisodeTwin, gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        task: int = 2,
        scene: Scene | None = None,
        config: SimConfig | None = None,
        max_episode_s: float = 180.0,
        control_hz: float = 10.0,
        cameras: tuple[str, ...] = (),
        image_size: tuple[int, int] = (160, 120),
        render_mode: str | None = None,
        wind: Wind | dict | None = None,
        start: SceneStart | dict | None = None,
    ) -> None:
        self.scene = scene or load_scene()
        self.wind = Wind.parse(wind)
        self.start = parse_start(start)
        self.task = self.scene.task(task)
        self.config = config or SimConfig()
        self.max_episode_s = max_episode_s
        self.control_hz = control_hz
        self.cameras = tuple(cameras)
        self.image_size = image_size
        self.render_mode = render_mode
        self.action_space = spaces.Box(-1.0, 1.0, (4,), np.float32)
        state = spaces.Box(-1e4, 1e4, (STATE_SIZE,), np.float32)
        if self.cameras:
            w, h = image_size
            self.observation_space = spaces.Dict(
                {
                    "state": state,
                    **{c: spaces.Box(0, 255, (h, w, 3), np.uint8) for c in self.cameras},
                }
            )
        else:
            self.observation_space = state
        end = self.scene.pad(self.task.end_pad)
        self.target_m = np.array([end.x_m, end.y_m, 0.0])
        self._renderer: Renderer | None = None

    # ---- gymnasium API ----
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        sim_seed = int(self.np_random.integers(0, 2**31 - 1))
        config = episode_config(self.config, sim_seed, self.wind, self.start, options)
        self._sim = sim = Sim(self.scene, config)
        sim.run_for(sim.config.sensors.gps_fix_delay_s + 0.5)
        ok, why = sim.arm()
        if not ok:
            raise RuntimeError(f"the twin refused to arm at reset: {why}")
        self._t0 = sim.t_s
        self.reward_fn = TaskReward(self.task, self.target_m, self.control_hz)
        self.reward_fn.reset(sim.state.pos_m[0])
        return self._observation(), self._info()

    def step(self, action):
        sim = self.sim
        a = np.clip(np.asarray(action, float), -1.0, 1.0)
        sim.set_sticks(a[0], a[1], a[2], 0.5 + 0.5 * a[3])
        sim.step(max(1, int(round(1.0 / (self.control_hz * sim.dt_s)))))
        crashed = bool(sim.state.crash[0])
        landed = not sim.commander.armed[0] and not crashed
        reward = self.reward_fn.step(sim.state.pos_m[0], crashed, landed)
        terminated = crashed or landed
        truncated = not terminated and sim.t_s - self._t0 >= self.max_episode_s
        return self._observation(), float(reward), terminated, truncated, self._info()

    def render(self):
        if self.render_mode != "rgb_array" or self._sim is None:
            return None
        return self._camera("front", full_size=True)

    # ---- helpers ----
    def _state_vector(self) -> np.ndarray:
        sim = self.sim
        pose = sim.pose()
        roll, pitch, _ = pose.euler_ned_rad
        yaw = pose.yaw_enu_rad
        rel = pose.pos_enu_m - self.target_m
        return np.concatenate(
            [
                rel,
                pose.vel_enu_mps,
                [roll, pitch, np.sin(yaw), np.cos(yaw)],
                pose.omega_body_rad_s,
                [
                    sim.battery_pct() / 100.0,
                    float(sim.commander.armed[0]),
                    float(sim.state.on_ground[0]),
                    float(np.hypot(rel[0], rel[1])),
                    float(rel[2]),
                ],
            ]
        ).astype(np.float32)

    def _observation(self):
        state = self._state_vector()
        if not self.cameras:
            return state
        return {"state": state, **{c: self._camera(c) for c in self.cameras}}

    def _camera(self, name: str, full_size: bool = False) -> np.ndarray:
        import cv2

        if self._renderer is None:
            from fpv_station.twin.render import Renderer

            self._renderer = Renderer(self.scene)
        bgr = self._renderer.render(name, self.sim.pose())
        if not full_size:
            bgr = cv2.resize(bgr, self.image_size, interpolation=cv2.INTER_AREA)
        return np.ascontiguousarray(bgr[..., ::-1])

    def _info(self) -> dict[str, Any]:
        sim = self.sim
        return {
            "t_s": sim.t_s - self._t0,
            "crash": sim.crash_reason(),
            "mode": sim.commander.mode_name(),
            "distance_m": self.reward_fn.distance_m,
            "pos_enu_m": sim.state.pos_m[0].copy(),
        }


def episode_config(
    config: SimConfig,
    seed: int,
    wind: Wind | None,
    start: SceneStart | None,
    options: dict[str, Any] | None,
) -> SimConfig:
    """The sim's configuration for an episode: `config` with the seed, and the wind and
    start of the reset `options` if given, else of the env (None: the scene's)."""
    options = options or {}
    unknown = set(options) - {"wind", "start"}
    if unknown:
        raise ValueError(f"unknown reset options: {', '.join(sorted(unknown))}")
    config = replace(config, seed=seed)
    wind = Wind.parse(options["wind"]) if "wind" in options else wind
    start = parse_start(options["start"]) if "start" in options else start
    if wind is not None:
        config = replace(config, wind=wind)
    if start is not None:
        config = replace(config, start=start)
    return config


def parse_start(value: SceneStart | dict | None) -> SceneStart | None:
    if value is None or isinstance(value, SceneStart):
        return value
    return SceneStart.model_validate(value)


class TaskReward:
    """The env's reward, from the vehicle's position alone, so that the rewards of a
    recorded flight can be recomputed exactly as the env gives them (exporters do).

    Progress: the decrease of the distance to the target each step; -0.01 per step;
    +10 on landing within 0.5 m of the target pad; -10 on a crash. Task 1's target is
    first the point `altitude_m` over the pad, until the vehicle has held within 0.3 m
    of that height for `hold_s` (steps of `1 / control_hz`), then the pad.
    """

    def __init__(self, task: Task, target_m: np.ndarray, control_hz: float) -> None:
        self.task = task
        self.target_m = np.asarray(target_m, float)
        self.step_s = 1.0 / control_hz
        self.hover_s = 0.0
        self.distance_m = 0.0

    def reset(self, pos_m: np.ndarray) -> None:
        self.hover_s = 0.0
        self.distance_m = self._distance(pos_m)

    def step(self, pos_m: np.ndarray, crashed: bool, landed: bool) -> float:
        dist = self._distance(pos_m)
        reward = (self.distance_m - dist) - 0.01
        self.distance_m = dist
        horizontal = float(np.hypot(*(pos_m[:2] - self.target_m[:2])))
        if self.task.id == 1 and abs(pos_m[2] - self.task.altitude_m) < 0.3:
            self.hover_s += self.step_s
        if crashed:
            reward -= 10.0
        elif landed and horizontal < 0.5:
            reward += 10.0
        return float(reward)

    def _distance(self, pos_m: np.ndarray) -> float:
        """To the target; task 1 first wants the hover point over the pad for `hold_s`."""
        target = self.target_m
        if self.task.id == 1 and self.hover_s < (self.task.hold_s or 10.0):
            target = target + [0.0, 0.0, self.task.altitude_m]
        return float(np.linalg.norm(np.asarray(pos_m, float) - target))


if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="fpv_station.twin.gym_env:TwinEnv")
