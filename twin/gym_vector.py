"""`TwinVectorEnv`: N twins in one batched `Sim`, as a Gymnasium vector environment.

Same actions, observations and rewards as `twin.gym_env.TwinEnv` (see its docstring), but
every array has a leading environment axis and all vehicles integrate together, which is
what makes the twin fast enough for learning (docs/PERFORMANCE.md). With `num_envs=1` and
the same seed it reproduces `TwinEnv` exactly.

Autoreset: next-step (Gymnasium's default). The step after an episode ends puts that
vehicle back on the start pad, armed, and returns its fresh observation with reward 0;
its action for that step is ignored (it idles on the pad for one control period).
With `autoreset=False` an ended vehicle is not reset and flies on (what follows its end
means nothing); every vehicle then draws its noise, gusts and turbulence from the batch's
streams exactly as at the reset, whatever the others do, so one seed gives the same N
episodes' air and starts to every policy (`learn.evaluate` compares policies so).
Wind and start: as `TwinEnv`'s (constructor or reset options).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from fpv_station.core.scene import Scene, SceneStart, load_scene
from fpv_station.twin.dynamics import Wind
from fpv_station.twin.gym_env import STATE_SIZE, EpisodeTwin, episode_config, parse_start
from fpv_station.twin.sim import Sim, SimConfig


class TwinVectorEnv(EpisodeTwin, VectorEnv):
    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        num_envs: int = 64,
        task: int = 2,
        scene: Scene | None = None,
        config: SimConfig | None = None,
        max_episode_s: float = 180.0,
        control_hz: float = 10.0,
        wind: Wind | dict | None = None,
        start: SceneStart | dict | None = None,
        autoreset: bool = True,
    ) -> None:
        self.num_envs = num_envs
        self.wind = Wind.parse(wind)
        self.start = parse_start(start)
        self.autoreset = autoreset
        self.scene = scene or load_scene()
        self.task = self.scene.task(task)
        self.config = config or SimConfig()
        self.max_episode_s = max_episode_s
        self.control_hz = control_hz
        self.single_action_space = spaces.Box(-1.0, 1.0, (4,), np.float32)
        self.single_observation_space = spaces.Box(-1e4, 1e4, (STATE_SIZE,), np.float32)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        end = self.scene.pad(self.task.end_pad)
        self.target_m = np.array([end.x_m, end.y_m, 0.0])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        n = self.num_envs
        sim_seed = int(self.np_random.integers(0, 2**31 - 1))
        config = episode_config(self.config, sim_seed, self.wind, self.start, options)
        self._sim = sim = Sim(self.scene, config, n=n)
        sim.run_for(sim.config.sensors.gps_fix_delay_s + 0.5)
        self._arm(np.arange(n))
        self._t0 = np.full(n, sim.t_s)
        self._hover_s = np.zeros(n)
        self._dist = self._distance()
        self._autoreset = np.zeros(n, bool)
        return self._observation(), {}

    def step(self, actions):
        sim = self.sim
        a = np.clip(np.asarray(actions, float).reshape(self.num_envs, 4), -1.0, 1.0)
        sim.sticks[:] = np.column_stack([a[:, :3], 0.5 + 0.5 * a[:, 3]])
        again = self._autoreset
        if again.any():
            sim.reset_vehicles(again)
            self._arm(np.nonzero(again)[0])
            self._t0[again] = sim.t_s
            self._hover_s[again] = 0.0
        sim.step(max(1, int(round(1.0 / (self.control_hz * sim.dt_s)))))

        pos = sim.state.pos_m
        crashed = sim.state.crash != 0
        landed = ~sim.commander.armed & ~crashed
        if self.task.id == 1:
            at_alt = np.abs(pos[:, 2] - self.task.altitude_m) < 0.3
            self._hover_s += at_alt / self.control_hz
        dist = self._distance()
        reward = (self._dist - dist) - 0.01
        self._dist = dist
        horizontal = np.hypot(pos[:, 0] - self.target_m[0], pos[:, 1] - self.target_m[1])
        reward -= 10.0 * crashed
        reward += 10.0 * (landed & (horizontal < 0.5))
        terminated = crashed | landed
        truncated = ~terminated & (sim.t_s - self._t0 >= self.max_episode_s)
        reward[again] = 0.0
        terminated[again] = False
        truncated[again] = False
        if self.autoreset:
            self._autoreset = terminated | truncated
        info = {"crash": sim.state.crash.copy(), "t_s": sim.t_s - self._t0}
        return self._observation(), reward.astype(np.float64), terminated, truncated, info

    def _arm(self, idx: np.ndarray) -> None:
        for i in idx:
            ok, why = self.sim.arm(i=int(i))
            if not ok:
                raise RuntimeError(f"the twin refused to arm vehicle {i}: {why}")

    def _distance(self) -> np.ndarray:
        target = np.tile(self.target_m, (self.num_envs, 1))
        if self.task.id == 1:
            target[self._hover_s < (self.task.hold_s or 10.0), 2] = self.task.altitude_m
        return np.linalg.norm(self.sim.state.pos_m - target, axis=1)

    def _observation(self) -> np.ndarray:
        sim, s = self.sim, self.sim.state
        R = s.R_world_body
        rel = s.pos_m - self.target_m
        yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
        return np.column_stack(
            [
                rel,
                s.vel_mps,
                np.arctan2(R[:, 2, 1], R[:, 2, 2]),
                np.arcsin(np.clip(R[:, 2, 0], -1, 1)),
                np.sin(yaw),
                np.cos(yaw),
                s.omega_rad_s,
                sim.battery_pct_all() / 100.0,
                sim.commander.armed,
                s.on_ground,
                np.hypot(rel[:, 0], rel[:, 1]),
                rel[:, 2],
            ]
        ).astype(np.float32)
