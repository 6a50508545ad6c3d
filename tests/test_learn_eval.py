"""`learn eval`'s statistics and rows: intervals against published values, seeds that keep
rows apart, and the open-loop replay, which passes in calm air and fails in wind."""

from __future__ import annotations

import numpy as np
import pytest

from fpv_station.core.scene import load_scene
from fpv_station.learn import evaluate as ev
from fpv_station.learn.demos import DemoConfig
from tests.demo_flights import shared_demo


def test_intervals_match_published_values() -> None:
    # Wilson's score interval, Newcombe (1998, Stat. Med. 17:857) table I: 81/263, 15/148,
    # 0/20, 1/29; and 9/10 -> 0.5958-0.9821.
    for (k, n), (lo, hi) in {
        (81, 263): (0.2553, 0.3662),
        (15, 148): (0.0624, 0.1605),
        (0, 20): (0.0, 0.1611),
        (1, 29): (0.0061, 0.1718),
        (9, 10): (0.5958, 0.9821),
    }.items():
        assert ev.wilson_interval(k, n) == pytest.approx((lo, hi), abs=1e-4)
    # 3 of 3 is anything from 44 % up, not "100 %".
    assert ev.wilson_interval(3, 3)[0] == pytest.approx(0.4385, abs=1e-4)
    assert all(np.isnan(ev.wilson_interval(0, 0)))
    # Newcombe (1998, Stat. Med. 17:873) method 10, 56/70 - 48/80: 0.0524 to 0.3339.
    assert ev.difference_interval(56, 70, 48, 80) == pytest.approx((0.2, 0.0524, 0.3339), abs=1e-4)
    # Student's t: 1..5 has mean 3, s = 1.5811, t(0.975, 4) = 2.7764.
    assert ev.mean_interval([1, 2, 3, 4, 5]) == pytest.approx((1.0368, 4.9632), abs=1e-4)
    assert all(np.isnan(ev.mean_interval([1.0])))


def test_random_rows_are_seeded_per_task_and_episode() -> None:
    """The random rows of tasks that start alike (3 and 4) were identical: same seeds."""

    def sticks(seed: int, task: int) -> np.ndarray:
        act = ev.random_policy(seed, task)
        return np.array([act(np.zeros(0), {}) for _ in range(20)])  # it reads no observation

    a = sticks(1000, 3)
    np.testing.assert_array_equal(a, sticks(1000, 3))
    assert not np.array_equal(a, sticks(1000, 4))
    assert not np.array_equal(a, sticks(1001, 3))


WIND = ev.air_options((1.414, 1.414), 0.5, 0.5, random_start_deg=180.0)


@pytest.mark.timeout(900)  # ~15 s alone
def test_open_loop_replay_passes_calm_and_fails_in_wind(tmp_path_factory) -> None:
    """A demonstration's recorded sticks, replayed blind on other seeds, land on the pad
    in still air from the pad's centre; in wind, from anywhere on the pad at any heading,
    they do not. The scripted pilot, which looks, lands in both."""
    # The task-2 flight tests/test_one_reader.py reads too: flown once (`shared_demo`).
    session = shared_demo(tmp_path_factory, 2, DemoConfig(task_id=2))
    (sticks,) = ev.recorded_sticks([session], 2, ev.CONTROL_HZ)
    replay = lambda s: ev.open_loop(sticks)  # noqa: E731
    calm = ev.evaluate("open-loop replay", replay, ev.EpisodeBatch(2, episodes=3, seed=1000))
    windy_batch = ev.EpisodeBatch(2, episodes=3, seed=1000, options=WIND)
    windy = ev.evaluate("open-loop replay", replay, windy_batch)
    assert calm.successes == 3, [o.why for o in calm.outcomes]
    assert windy.successes == 0
    scene = load_scene()
    pilot = ev.evaluate(
        "scripted pilot", lambda s: ev.scripted_pilot(scene, 2), ev.EpisodeBatch(2, 2, 1000, WIND)
    )
    assert pilot.successes == 2, [o.why for o in pilot.outcomes]
