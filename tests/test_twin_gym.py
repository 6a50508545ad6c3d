"""The Gymnasium environment on the twin: the contract, determinism, episode ends."""

from __future__ import annotations

import numpy as np
from gymnasium.utils.env_checker import check_env

from fpv_station.twin.gym_env import TwinEnv
from fpv_station.twin.pilot import Observation, Pilot, task_plan


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
        roll, pitch, yaw, thr = pilot.update(
            Observation(
                env.sim.t_s,
                p.pos_enu_m,
                p.vel_enu_mps,
                p.yaw_enu_rad,
                bool(env.sim.commander.armed[0]),
            )
        )
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


def test_vector_env_with_one_env_reproduces_the_single_env() -> None:
    from fpv_station.twin.gym_vector import TwinVectorEnv

    single, vector = TwinEnv(task=2), TwinVectorEnv(num_envs=1, task=2)
    o1, _ = single.reset(seed=5)
    ov, _ = vector.reset(seed=5)
    np.testing.assert_allclose(ov[0], o1, atol=1e-6)
    rng = np.random.default_rng(0)
    for _ in range(30):
        a = rng.uniform(-1, 1, 4).astype(np.float32)
        o1, r1, *_ = single.step(a)
        ov, rv, *_ = vector.step(a[None])
        np.testing.assert_allclose(ov[0], o1, atol=1e-5)
        assert rv[0] == np.float64(r1) or abs(rv[0] - r1) < 1e-9


def test_vector_env_autoresets_one_crashed_vehicle_and_not_the_others() -> None:
    from fpv_station.twin.gym_vector import TwinVectorEnv

    env = TwinVectorEnv(num_envs=8, task=2)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (8, 18) and env.observation_space.contains(obs)
    climb = np.tile([0.0, 0.0, 0.0, 0.5], (8, 1)).astype(np.float32)
    for _ in range(20):
        env.step(climb)  # ~2 m: below the obstacles
    go = climb.copy()
    go[0] = [0.0, 0.6, 0.0, 0.0]  # vehicle 0 flies east into obstacle 1, the rest hover
    go[1:, 3] = 0.0
    for _ in range(300):
        obs, reward, terminated, truncated, info = env.step(go)
        if terminated[0]:
            break
    assert terminated[0] and info["crash"][0] == 2 and reward[0] < -9
    assert not terminated[1:].any() and (obs[1:, 2] > 1.0).all()  # the others still fly
    obs, reward, terminated, truncated, _ = env.step(go)
    assert reward[0] == 0.0 and not terminated[0]
    start = env.scene.pad("start")
    assert obs[0, 0] == np.float32(start.x_m - env.target_m[0])  # back on the start pad
    assert env.sim.commander.armed[0]
