"""The learning loop on task 1 (hover), small enough for CI: `demos` flies the scripted
pilot into sessions, `export` makes a LeRobot dataset of them, `learn bc` trains a policy,
and `learn eval` flies it in the twin next to the scripted pilot, the open-loop replay of
the demonstrations' sticks, a random policy and the demonstrations, scored with the
paper's metrics and their intervals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fpv_station.learn.bc import FEATURES, BcPolicy
from fpv_station.server.cli import main as cli_main
from tests.helpers import eval_rows


@pytest.mark.timeout(900)  # ~25 s alone; minutes when the machine is shared
def test_demos_bc_eval_on_the_hover(tmp_path: Path, capsys):
    demos = tmp_path / "demos"
    assert (
        cli_main(["demos", "--task", "1", "--count", "4", "--seed", "50", "--out", str(demos)]) == 0
    )
    sessions = sorted(p for p in demos.iterdir() if p.is_dir())
    assert len(sessions) == 4
    dataset = tmp_path / "dataset"
    argv = ["export", *map(str, sessions), "--format", "lerobot", "--out", str(dataset)]
    # One process: worker processes (tests/test_export.py) would each import the export.
    assert cli_main([*argv, "--task", "1", "--workers", "1", "--no-progress"]) == 0
    policy = tmp_path / "policy.npz"
    assert cli_main(["learn", "bc", str(dataset), "--out", str(policy)]) == 0
    capsys.readouterr()
    p = BcPolicy.load(policy)
    assert p.task_id == 1 and p.inputs.shape[1] == len(FEATURES) + 1
    assert np.allclose(p.act(np.zeros(18), 0.0).shape, (4,))

    argv = ["learn", "eval", str(policy), "--task", "1", "--episodes", "3", "--seed", "1000"]
    assert cli_main([*argv, "--demos", *map(str, sessions)]) == 0
    out = capsys.readouterr().out
    rows = eval_rows(out)
    # columns: scored on, episodes, success [95%], crashes, hover distance [95%],
    # height dev. [95%], trial time [95%], time; a figure is "value [low, high]"
    first = {k: [c.split(" ")[0] for c in v] for k, v in rows.items()}
    bc, scripted, rnd, demo = (
        first["behaviour cloning"],
        first["scripted pilot"],
        first["random"],
        first["scripted demonstrations"],
    )
    assert bc[1] == "3" and demo[1] == "4" and first["open-loop replay"][1] == "3"
    assert rows["scripted demonstrations"][0] == "recorded GPS + baro"
    assert {v[0] for k, v in rows.items() if k != "scripted demonstrations"} == {"true state"}
    assert rows["scripted pilot"][2] == "100% [44%, 100%]"  # 3 of 3: Wilson's interval
    success = {k: int(v[2].rstrip("%")) for k, v in first.items()}
    assert success["behaviour cloning"] >= 66  # at least 2 of 3 landed on the pad
    assert success["random"] == 0  # the clear margin
    assert success["scripted pilot"] == 100 and success["scripted demonstrations"] == 100
    assert bc[3] == "0"  # no crash
    # The paper's hover metrics: the clone hovers over the pad, like its teachers.
    assert float(bc[4]) < 0.5 and float(demo[4]) < 0.5
    assert 10.0 < float(bc[6]) < 40.0  # trial time: climb, 10 s hold, descent
    assert float(scripted[6]) == pytest.approx(19.0, abs=1.5)
    assert float(rnd[-1]) == pytest.approx(60.0)  # random never lands: the time limit
    assert "behaviour cloning - random, success: +" in out


def test_learn_errors_are_clear(tmp_path: Path, capsys):
    assert cli_main(["learn", "bc", str(tmp_path), "--out", str(tmp_path / "p.npz")]) == 1
    assert "not a LeRobot dataset" in capsys.readouterr().err
    bogus = tmp_path / "bogus.npz"
    np.savez(bogus, x=np.zeros(3))
    assert cli_main(["learn", "eval", str(bogus), "--task", "1", "--episodes", "1"]) == 1
    assert "not an fpv-station behaviour-cloning policy" in capsys.readouterr().err
    assert cli_main(["demos", "--task", "1", "--count", "0", "--out", str(tmp_path)]) == 2
