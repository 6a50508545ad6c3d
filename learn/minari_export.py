"""A Minari dataset (offline RL) whose environment is the twin's `TwinEnv` for the task.

`minari.load_dataset(ID).recover_environment()` builds `TwinEnv(task=N)` from the stored
env spec (entry point `fpv_station.twin.gym_env:TwinEnv`, id `twin.gym_env.ENV_ID`), so a policy
trained on the dataset is evaluated in the twin without glue. Each flight is one episode:

- observations: the env's state vector (`twin.gym_env.STATE_NAMES`) at every frame,
  T + 1 of them; actions: the sticks held from each frame to the next, T of them;
- rewards: recomputed with the env's own reward function (`twin.gym_env.TaskReward`)
  from the recorded positions, step by step as `TwinEnv.step` gives them;
- terminations: the last step of a flight that ended landed (disarmed on the ground);
  truncations: the last step of one cut off by the end of its recording.

The dataset is written under `--out DIR` (Minari's `MINARI_DATASETS_PATH` while
writing), with Minari's arrow data format. Its id: `fpv-station/twin-task{N}/demos-v0`
unless given. Episodes are state vectors only (a flight-minute at 10 fps is ~7 kB), held
until the dataset is written.
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fpv_station.learn.episodes import Episode, target_m
from fpv_station.twin.gym_env import ENV_ID, TaskReward

if TYPE_CHECKING:  # imported on use: minari is an optional extra
    from minari.data_collector.episode_buffer import EpisodeBuffer

DATA_FORMAT = "arrow"


def default_dataset_id(task_id: int) -> str:
    return f"fpv-station/twin-task{task_id}/demos-v0"


def episode_buffer(ep: Episode, scene, task_id: int, fps: float) -> EpisodeBuffer:
    """One Minari `EpisodeBuffer` from an episode, rewards recomputed by the env's rule."""
    from minari.data_collector.episode_buffer import EpisodeBuffer

    n = len(ep)
    target = target_m(scene, task_id)
    reward_fn = TaskReward(scene.task(task_id), target, fps)
    pos = ep.state[:, :3].astype(np.float64) + target
    reward_fn.reset(pos[0])
    steps = max(n - 1, 0)
    rewards = np.array(
        [reward_fn.step(pos[k], False, ep.landed and k == n - 1) for k in range(1, n)],
        dtype=np.float64,
    )
    term = np.zeros(steps, bool)
    trunc = np.zeros(steps, bool)
    if steps:
        term[-1] = ep.landed
        trunc[-1] = not ep.landed
    return EpisodeBuffer(
        observations=ep.state.astype(np.float32),
        actions=ep.action[:steps].astype(np.float32),
        rewards=rewards,
        terminations=term,
        truncations=trunc,
    )


class MinariExport:
    """`learn.export`'s adapter: episodes buffered, one Minari dataset written at close."""

    def __init__(self, out: Path, options, scene, task: str):
        self.out = Path(out)
        self.options = options
        self.scene = scene
        self.task = task
        self.dataset_id = (
            options.dataset_id
            if _is_minari_id(options.dataset_id)
            else default_dataset_id(options.task_id)
        )
        self.buffers: list[EpisodeBuffer] = []

    def add(self, ep: Episode) -> None:
        if len(ep) >= 2:
            self.buffers.append(
                episode_buffer(ep, self.scene, self.options.task_id, self.options.fps)
            )

    def close(self, summary) -> None:
        import gymnasium as gym
        import minari

        from fpv_station.twin.gym_env import TwinEnv

        if not self.buffers:
            raise ValueError("no episode of two frames or more to write")
        spec = gym.envs.registration.EnvSpec(
            id=ENV_ID,
            entry_point=gym.spec(ENV_ID).entry_point,
            kwargs={"task": self.options.task_id, "control_hz": float(self.options.fps)},
        )
        probe = TwinEnv(task=self.options.task_id, control_hz=float(self.options.fps))
        self.out.mkdir(parents=True, exist_ok=True)
        previous = os.environ.get("MINARI_DATASETS_PATH")
        os.environ["MINARI_DATASETS_PATH"] = str(self.out.resolve())
        try:
            with warnings.catch_warnings():
                # Minari asks for a code permalink and an author e-mail: a local export has none.
                warnings.simplefilter("ignore", UserWarning)
                minari.create_dataset_from_buffers(
                    dataset_id=self.dataset_id,
                    buffer=self.buffers,
                    env=spec,
                    eval_env=spec,
                    algorithm_name="human and scripted FPV pilots (fpv-station recordings)",
                    author="fpv-station",
                    action_space=probe.action_space,
                    observation_space=probe.observation_space,
                    description=f"Task {self.options.task_id}: {self.task}",
                    data_format=DATA_FORMAT,
                    requirements=["fpv-station[learn]"],
                )
        finally:
            if previous is None:
                os.environ.pop("MINARI_DATASETS_PATH", None)
            else:
                os.environ["MINARI_DATASETS_PATH"] = previous


def _is_minari_id(text: str) -> bool:
    return re.fullmatch(r"([\w-]+/){0,2}[\w-]+-v\d+", text) is not None
