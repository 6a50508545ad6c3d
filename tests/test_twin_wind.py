"""The twin's air (mean wind, gusts, Dryden-like turbulence) and its seeded random start:
deterministic for a seed, statistically what `twin.dynamics.Wind` says, and off unless
configured (the pilot's station flies in calm air from the pad's centre)."""

from __future__ import annotations

import numpy as np
import pytest

from fpv_station.core.scene import load_scene
from fpv_station.twin.dynamics import Dynamics, Wind, dryden_low_altitude
from fpv_station.twin.gym_env import TwinEnv
from fpv_station.twin.runner import twin_from_settings
from fpv_station.twin.settings import TwinSettings
from fpv_station.twin.sim import Sim, SimConfig

WINDY = {"mean_enu_mps": [2.0, 0.0, 0.0], "gust_std_mps": 0.5, "turbulence_std_mps": 0.5}


def hover_track(seed: int, options: dict | None = None, steps: int = 60) -> np.ndarray:
    """Positions of a `TwinEnv` episode with the sticks centred but for a climb."""
    env = TwinEnv(task=1)
    env.reset(seed=seed, options=options)
    out = []
    for k in range(steps):
        _, _, term, trunc, info = env.step([0.0, 0.0, 0.0, 1.0 if k < 15 else 0.0])
        out.append(info["pos_enu_m"])
        assert not (term or trunc)
    return np.array(out)


def test_wind_moves_the_vehicle_deterministically_for_a_seed() -> None:
    calm = hover_track(5)
    windy = hover_track(5, {"wind": WINDY})
    np.testing.assert_array_equal(windy, hover_track(5, {"wind": WINDY}))
    assert not np.array_equal(windy, hover_track(6, {"wind": WINDY}))
    # Position mode holds the spot in calm air; the wind pushes it off while the
    # integrator catches up, and gusts keep it moving.
    drift = lambda p: float(np.max(np.hypot(*(p[:, :2] - p[0, :2]).T)))  # noqa: E731
    assert drift(calm) < 0.1
    assert drift(windy) > 2 * drift(calm) + 0.05


def test_turbulence_and_gusts_have_the_documented_statistics() -> None:
    """Thousands of vehicles held at 4 m: the stationary sigma of each axis, and the
    one-step correlation exp(-V dt / L) of Dryden's low-altitude length scales."""
    n, sigma, dt = 4000, 0.8, 0.1
    dyn = Dynamics(wind=Wind((0.0, 0.0, 0.0), turbulence_std_mps=sigma), seed=11)
    s = dyn.initial_state(n, np.zeros(2))
    s.pos_m[:, 2] = 4.0
    ratio, length = dryden_low_altitude(np.array([4.0]))
    # Known values (MIL-F-8785C, h = 4 m = 13.12 ft, 0.177 + 0.000823 h = 0.1878):
    # sigma_w / sigma_u = 0.1878^0.4 = 0.5122,
    # L_u = 97.65 ft = 29.76 m, L_w = 4 m.
    assert ratio[0, 2] == pytest.approx(0.5122, abs=1e-3)
    assert length[0, 0] == pytest.approx(29.76, abs=0.02) and length[0, 2] == pytest.approx(4.0)
    for _ in range(50):
        dyn.slow_update(s, dt)
    before = s.turbulence_mps.copy()
    dyn.slow_update(s, dt)
    after = s.turbulence_mps
    std = after.std(axis=0)
    np.testing.assert_allclose(std, sigma * ratio[0], rtol=0.06)
    # Hovering: the air passes at the mean wind (0) -> the 1 m/s floor.
    rho = (before * after).mean(axis=0) / (before.std(axis=0) * after.std(axis=0))
    np.testing.assert_allclose(rho, np.exp(-dt * 1.0 / length[0]), atol=0.02)
    np.testing.assert_allclose(s.wind_mps, after)  # no mean, no gusts

    gusty = Dynamics(wind=Wind((1.0, -1.0, 0.0), gust_std_mps=0.5, gust_tau_s=2.0), seed=12)
    g = gusty.initial_state(n, np.zeros(2))
    first = g.gust_mps.copy()
    gusty.slow_update(g, dt)
    np.testing.assert_allclose(g.gust_mps.std(axis=0), 0.5, rtol=0.06)
    rho = (first * g.gust_mps).mean(axis=0) / (first.std(axis=0) * g.gust_mps.std(axis=0))
    np.testing.assert_allclose(rho, np.exp(-dt / 2.0), atol=0.02)
    np.testing.assert_allclose(g.wind_mps.mean(axis=0), [1.0, -1.0, 0.0], atol=0.03)


def test_random_start_is_on_the_pad_seeded_and_off_by_default() -> None:
    scene = load_scene()
    pad = scene.pads[0]
    default = Sim(scene, SimConfig(seed=1), n=3)
    np.testing.assert_array_equal(default.state.pos_m[:, :2], np.tile(pad.xy_m, (3, 1)))
    np.testing.assert_array_equal(
        default.state.R_world_body[:, :, :], np.tile(np.eye(3), (3, 1, 1))
    )
    assert default.wind.calm and not default.state.wind_mps.any()

    starts = []
    for seed in range(40):
        env = TwinEnv(task=2, start={"random": True, "heading_deg": 90.0})
        obs, info = env.reset(seed=seed)
        starts.append((*info["pos_enu_m"][:2], np.arctan2(obs[8], obs[9])))
    start_poses = np.array(starts)
    assert np.all(np.abs(start_poses[:, :2] - pad.xy_m) <= pad.size_m / 2)
    assert np.all(np.abs(start_poses[:, 2]) <= np.pi / 2 + 1e-6)
    # spread over the pad and the headings, not a few fixed spots
    assert np.ptp(start_poses[:, 0]) > pad.size_m / 2 and np.ptp(start_poses[:, 1]) > pad.size_m / 2
    assert np.ptp(start_poses[:, 2]) > np.pi / 2
    again = TwinEnv(task=2, start={"random": True, "heading_deg": 90.0})
    _, info = again.reset(seed=39)
    np.testing.assert_array_equal(info["pos_enu_m"][:2], start_poses[-1, :2])
    with pytest.raises(ValueError, match="unknown reset options"):
        again.reset(seed=1, options={"gusts": 1.0})
    with pytest.raises(ValueError, match="unknown wind fields"):
        again.reset(seed=1, options={"wind": {"speed": 1.0}})


def test_station_twin_is_calm_unless_configured() -> None:
    calm = twin_from_settings(TwinSettings(), mavlink=None)
    assert calm.sim.wind.calm and not calm.sim.start.random
    windy = twin_from_settings(
        TwinSettings(wind_east_mps=2.0, gust_std_mps=0.5, turbulence_std_mps=0.3), mavlink=None
    )
    assert windy.sim.wind == Wind((2.0, 0.0, 0.0), gust_std_mps=0.5, turbulence_std_mps=0.3)


def test_batch_without_autoreset_gives_every_policy_the_same_episodes() -> None:
    """What `learn eval` relies on to compare rows pair by pair: in a batch that does not
    autoreset, what vehicle 0 does (here: fly it into the net) changes nothing for the
    others; an autoreset of it would have drawn its fresh start from the shared streams."""
    from fpv_station.twin.gym_vector import TwinVectorEnv

    def run(first: list[float]) -> np.ndarray:
        env = TwinVectorEnv(num_envs=3, task=2, autoreset=False, max_episode_s=30.0)
        env.reset(seed=9, options={"wind": WINDY, "start": {"random": True}})
        crashed = False
        for k in range(80):
            up = [0.0, 0.0, 0.0, 1.0 if k < 15 else 0.0]
            _, _, term, _, _ = env.step(np.array([first if k > 15 else up, up, up], np.float32))
            crashed |= bool(term[0])
        assert crashed == (first[1] < 0)
        s = env.sim.state
        return np.concatenate([s.pos_m, s.wind_mps, s.turbulence_mps], axis=1)

    a, b = run([0.0, 0.0, 0.0, 0.0]), run([0.0, -1.0, 0.0, 0.0])  # backwards: the net
    assert not np.allclose(a[0], b[0])
    np.testing.assert_array_equal(a[1:], b[1:])
