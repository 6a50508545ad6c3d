"""A LeRobot policy folder flown by `learn eval`, without torch: the numpy stand-in
(`learn.linear_policy`) is saved as `lerobot-train` saves a policy (config.json,
model.safetensors, the processors' json and safetensors) and goes through the bridge's
whole path (`learn.lerobot_policy`): loading, the observation at the dataset's rate
with the twin's camera images at the dataset's size, its actions flown as sticks, and
its row in `learn eval`'s table, on a short task-1 dataset from `demos` and `export`."""

from __future__ import annotations

import json
from pathlib import Path

import av
import numpy as np
import pytest

from fpv_station.learn import evaluate as ev
from fpv_station.learn.demos import DemoConfig
from fpv_station.learn.lerobot_policy import LeRobotPolicy
from fpv_station.learn.linear_policy import EPS, LinearPolicy
from fpv_station.server.cli import main as cli_main
from fpv_station.twin.gym_vector import TwinVectorEnv
from tests.demo_flights import shared_demo

FPS = 5  # not the env's 10 Hz: the policy must be asked at the dataset's rate
SIZE = (64, 48)
SEED = 1000
# The height holder never lands: its episodes end at this limit, not the task's 60 s. It
# is long enough for the hover's analysis (up to 4 m, then 10 s there) to hold.
EPISODE_S = 20.0
# One demo (~15 s alone, minutes on a shared machine) and two short episodes in the twin.
pytestmark = pytest.mark.timeout(900)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    # Pictures at the dataset's rate: the export takes no more of them.
    config = DemoConfig(task_id=1, cameras=True, camera_fps=FPS, hold_s=2.0)
    demo = shared_demo(tmp_path_factory, 7, config)
    out = tmp_path_factory.mktemp("lerobot")
    argv = ["export", str(demo), "--format", "lerobot", "--out", str(out), "--fps", str(FPS)]
    assert cli_main([*argv, "--image-size", "{}x{}".format(*SIZE), "--no-progress"]) == 0
    return out


def _height_holder(dataset: Path) -> tuple[LinearPolicy, np.ndarray, np.ndarray]:
    """The stand-in with the dataset's normalization and weights that climb to 4 m and
    hold over the pad: sticks = clip(K state + c) in the dataset's units."""
    p = LinearPolicy.fit(dataset)
    K = np.zeros((4, 18), np.float32)
    # Facing east (the start's heading): pitch forward flies east, roll right south.
    K[1, 0], K[0, 1] = -0.5, 0.5
    K[3, 2] = -0.8  # throttle against the height to the target ...
    c = np.array([0, 0, 0, 0.8 * 4.0], np.float32)  # ... about 4 m
    a_std = p.action_std + EPS  # LeRobot's normalizer divides by std + eps (a still yaw: 0)
    p.state_weight = (K * (p.state_std + EPS)[None, :] / a_std[:, None]).astype(np.float32)
    p.bias = ((K @ p.state_mean + c - p.action_mean) / a_std).astype(np.float32)
    return p, K, c


def test_a_stand_in_folder_is_found_and_scored_in_the_table(dataset, tmp_path, capsys):
    # As lerobot-train writes it: OUT/checkpoints/NNNNNN/pretrained_model, `last` linked
    # to the newest, the dataset the run was trained on in train_config.json.
    out = tmp_path / "train"
    folder = out / "checkpoints" / "000100" / "pretrained_model"
    LinearPolicy.fit(dataset).save_pretrained(folder)
    (out / "checkpoints" / "last").symlink_to("000100")
    (folder / "train_config.json").write_text(
        json.dumps({"dataset": {"repo_id": "fpv-station/demonstrations", "root": str(dataset)}})
    )
    argv = ["learn", "eval", str(out), "--task", "1", "--episodes", "1", "--no-baselines"]
    assert cli_main(argv) == 0
    out, err = capsys.readouterr()
    assert "LeRobot fpv_linear: front, bottom cameras, 5 fps, task 'Take off, hover" in err
    assert f"(from {dataset})" in err
    row = [line for line in out.splitlines() if line.startswith("| LeRobot fpv_linear |")]
    assert len(row) == 1 and "| true state | 1 |" in row[0]

    # A folder that is not a policy, a policy that reads what the twin lacks: clear errors.
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "config.json").write_text("{}")
    assert cli_main(["learn", "eval", str(tmp_path / "empty"), "--task", "1"]) == 1
    assert "is not a LeRobot policy config" in capsys.readouterr().err
    config = json.loads((folder / "config.json").read_text())
    config["input_features"]["observation.images.left_wrist"] = config["input_features"].pop(
        "observation.images.front"
    )
    (folder / "config.json").write_text(json.dumps(config))
    assert cli_main(["learn", "eval", str(folder), "--task", "1"]) == 1
    assert "reads camera 'left_wrist'; the twin has front, bottom" in capsys.readouterr().err


def test_the_policy_sees_what_the_export_gave_it_and_flies_its_actions(dataset, tmp_path):
    stand_in, K, c = _height_holder(dataset)
    folder = stand_in.save_pretrained(tmp_path / "pretrained_model")
    policy = LeRobotPolicy(folder, 1, dataset)
    assert policy.control_hz == FPS and policy.inputs.images == {"front": SIZE, "bottom": SIZE}

    seen: list[dict] = []  # every batch the policy is given, after its preprocessor
    model = policy._runtime.policy
    select = model.select_action
    model.select_action = lambda batch: (seen.append(batch), select(batch))[1]
    batch = ev.EpisodeBatch(1, episodes=2, seed=SEED, max_episode_s=EPISODE_S)
    row = ev.policy_row(policy, batch)
    assert row.name == "LeRobot fpv_linear"

    # The rate: one call per dataset frame (0.2 s of flight), until both episodes ended.
    longest = max(o.time_s for o in row.outcomes)
    assert len(seen) == pytest.approx(longest * FPS, abs=1)
    # The state: the env's observation, normalized with the dataset's stats.
    first = seen[0]["observation.state"] * (stand_in.state_std + EPS) + stand_in.state_mean
    obs0, _ = TwinVectorEnv(num_envs=2, task=1, control_hz=FPS, autoreset=False).reset(seed=SEED)
    np.testing.assert_allclose(first, obs0, atol=1e-4)
    # The task text and the images: RGB in [0, 1] at the dataset's size ...
    assert seen[0]["task"][0].startswith("Take off, hover, land")
    for cam in ("front", "bottom"):
        img = seen[0][f"observation.images.{cam}"]
        assert img.shape == (2, 3, SIZE[1], SIZE[0]) and img.dtype == np.float32
        assert 0.0 <= img.min() and img.max() <= 1.0 and img.std() > 0.02
    # ... and, on the pad before take-off, each camera's picture is the dataset's first
    # frame of that camera (the demo stood on the same spot, give or take a few cm), not
    # the other camera's, nor with its colours (BGR) or rows (upside down) swapped.
    front = seen[0]["observation.images.front"][0]
    bottom = seen[0]["observation.images.bottom"][0]
    recorded_front, recorded_bottom = (
        _first_frame(dataset, "front"),
        _first_frame(dataset, "bottom"),
    )
    diff = np.abs(front - recorded_front).mean()
    assert diff < 0.06
    for wrong in (bottom, front[::-1], front[:, ::-1]):
        assert np.abs(wrong - recorded_front).mean() > 3 * diff
    diff = np.abs(bottom - recorded_bottom).mean()
    assert np.abs(front - recorded_bottom).mean() > 3 * diff

    # Its actions flown as the sticks: the same flights as K state + c flown directly.
    def direct(obs: np.ndarray, info: dict) -> np.ndarray:
        return np.clip(K @ obs + c, -1, 1).astype(np.float32)

    reference = ev.fly_episodes([direct, direct], batch, control_hz=FPS)
    for got, want in zip(row.outcomes, reference, strict=True):
        assert got.result is not None and want.result is not None  # it reached 4 m
        assert got.time_s == want.time_s and got.crashed == want.crashed == False  # noqa: E712
        assert got.result.hover_distance_m == pytest.approx(want.result.hover_distance_m, abs=1e-3)
        assert got.result.height_deviation_m == pytest.approx(
            want.result.height_deviation_m, abs=1e-3
        )


def _first_frame(dataset: Path, cam: str) -> np.ndarray:
    """(3, H, W) in [0, 1]: the camera's first video frame in the dataset."""
    path = next((dataset / "videos" / f"observation.images.{cam}").glob("*/*.mp4"))
    with av.open(str(path)) as c:
        frame = next(c.decode(video=0)).to_ndarray(format="rgb24")
    return frame.transpose(2, 0, 1).astype(np.float32) / 255.0
