"""The Gymnasium environment on the twin: the contract, determinism, episode ends."""

from __future__ import annotations

import numpy as np
from gymnasium.utils.env_checker import check_env

from twin.gym_env import TwinEnv
from twin.pilot import Observation, Pilot, task_plan


def test_check_env_passes_with_and_without_cameras() -> None:
    check_env(TwinEnv(max_episode_s=5.0), skip_render_check=True)
    env = TwinEnv(max_episode_s=2.0, cameras=("bottom",), render_mode="rgb_array")
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=1)
    assert obs["bottom"].shape == (120, 160, 3)
    assert env.render().shape == (480, 640, 3)


def rollout(seed: int, steps: int = 40) -> np.ndarray:
    env = TwinEnv(task=2)
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    out = [obs]
    for _ in range(steps):
        obs, *_ = env.step(env.action_space.sample())
        out.append(obs)
    return np.array(out)


def test_same_seed_same_episode() -> None:
    a, b = rollout(3), rollout(3)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, rollout(4))


def test_scripted_pilot_earns_the_landing_bonus() -> None:
    """The pilot's sticks, given as actions, fly task 2 to the end: progress + bonus."""
    env = TwinEnv(task=2, max_episode_s=150.0)
    env.reset(seed=0)
    pilot = Pilot(task_plan(env.scene, 2)[1:])  # the env arms at reset
    total, terminated, truncated = 0.0, False, False
    while not (terminated or truncated):
        p = env.sim.pose()
        roll, pitch, yaw, thr = pilot.update(Observation(
            env.sim.t_s, p.pos_enu_m, p.vel_enu_mps, p.yaw_enu_rad, bool(env.sim.commander.armed[0])))
        _, reward, terminated, truncated, info = env.step([roll, pitch, yaw, 2 * thr - 1])
        total += reward
    assert terminated and info["crash"] == ""
    assert total > 10.0 + 0.8 * 40.0 - 0.01 * 1500  # ~40 m of progress and the bonus


def test_crash_terminates_with_penalty() -> None:
    env = TwinEnv(task=2)
    env.reset(seed=0)
    for _ in range(20):  # climb to ~2 m: below the 3 m obstacles
        env.step([0, 0, 0, 0.5])
    rewards = []
    for _ in range(300):
        _, reward, terminated, truncated, info = env.step([0, 0.6, 0, 0])  # east, into obstacle 1
        rewards.append(reward)
        if terminated:
            break
    assert terminated and info["crash"] == "obstacle" and rewards[-1] < -9
