"""The vision policy (`learn.vision`): the pad found in the twin's real bottom-camera
renders, and the policy trained on a demonstration exported with the bottom camera,
flown by `learn eval` from the picture and the attitude, landing on the pad."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import pytest

from fpv_station.core.scene import load_scene
from fpv_station.learn.vision import (
    ATTITUDE,
    VisionPolicy,
    inputs_of,
    pad_features,
    pad_view,
    world_from_attitude,
)
from fpv_station.server.cli import main as cli_main
from fpv_station.twin.render import Renderer, bottom_camera
from fpv_station.twin.sim import Pose
from tests.helpers import eval_rows

SIZE = (160, 120)  # TwinEnv's pictures


@pytest.fixture(scope="module")
def renderer() -> Renderer:
    return Renderer(load_scene())


def _rotation(roll: float, pitch: float, yaw_enu: float) -> np.ndarray:
    """R_world_body (ENU, FLU) for a heading and small roll (right down) and pitch (nose up)."""

    def rx(a):
        return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])

    def ry(a):
        return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])

    def rz(a):
        return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])

    return rz(yaw_enu) @ ry(-pitch) @ rx(roll)


def _picture(renderer: Renderer, pos: Sequence[float], R: np.ndarray) -> np.ndarray:
    """The bottom camera as TwinEnv gives it: rendered, area-resized, RGB."""
    pose = Pose(0.0, np.asarray(pos, float), np.zeros(3), R, np.zeros(3))
    bgr = cv2.resize(renderer.render("bottom", pose), SIZE, interpolation=cv2.INTER_AREA)
    return bgr[..., ::-1]


@pytest.mark.parametrize(
    ("offset", "height", "attitude"),
    [
        ((0.0, 0.0), 4.0, (0.0, 0.0, 0.0)),
        ((0.6, -0.4), 4.0, (0.0, 0.0, 0.0)),
        ((-0.5, 0.3), 3.0, (0.08, -0.06, 0.0)),  # tilted: the picture moves, not the pad
        ((0.2, 0.3), 2.0, (-0.05, 0.06, np.pi / 2)),  # facing north
        ((0.0, 0.0), 1.5, (0.0, 0.0, -2.5)),
    ],
)
def test_pad_features_find_the_vehicle_over_the_pad(renderer, offset, height, attitude):
    pad = load_scene().pad("start")
    R = _rotation(*attitude)
    pos = np.array([pad.x_m + offset[0], pad.y_m + offset[1], height])
    view = pad_view(_picture(renderer, pos, R), 90.0)
    assert view.visible and not view.clipped
    east, north, h = pad_features(view, R, pad.size_m, bottom_camera())
    assert h == pytest.approx(height, abs=0.1 * height / 4 + 0.05)
    assert (east, north) == pytest.approx(offset, abs=0.12)


def test_the_pad_from_the_ground_and_out_of_view(renderer):
    pad = load_scene().pad("start")
    level = _rotation(0.0, 0.0, 0.0)
    on_pad = pad_view(_picture(renderer, [pad.x_m, pad.y_m, 0.0], level), 90.0)
    assert on_pad.visible and on_pad.clipped  # it fills the picture
    # Its apparent height is a floor well under the hover's 4 m
    assert pad_features(on_pad, level, pad.size_m, bottom_camera())[2] < 1.0
    grass = pad_view(_picture(renderer, [pad.x_m + 8.0, pad.y_m, 4.0], level), 90.0)
    assert not grass.visible
    assert np.isnan(pad_features(grass, level, pad.size_m, bottom_camera())[2])


def test_attitude_gives_the_body_rotation() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        roll, pitch, yaw = rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-3, 3)
        R = _rotation(roll, pitch, yaw)
        pose = Pose(0.0, np.zeros(3), np.zeros(3), R, np.zeros(3))
        r, p, _ = pose.euler_ned_rad
        y = pose.yaw_enu_rad
        assert np.allclose(world_from_attitude(r, p, np.sin(y), np.cos(y)), R, atol=1e-12)


def test_inputs_read_the_attitude_only(renderer):
    """Position, velocity and distances in the state vector change nothing."""
    pad = load_scene().pad("start")
    rgb = _picture(renderer, [pad.x_m + 0.3, pad.y_m, 4.0], _rotation(0.0, 0.0, 0.0))
    view = pad_view(rgb, 90.0)
    state = np.zeros(18)
    state[[8, 9]] = 0.0, 1.0  # facing east
    other = np.random.default_rng(0).normal(0, 5, 18)
    other[list(ATTITUDE)] = state[list(ATTITUDE)]
    a = inputs_of(view, state, 5.0, pad.size_m, bottom_camera())
    b = inputs_of(view, other, 5.0, pad.size_m, bottom_camera())
    assert np.array_equal(a, b)


@pytest.mark.timeout(600)  # ~40 s alone; minutes when the machine is shared
def test_trained_on_one_demonstration_it_lands_on_the_pad(tmp_path: Path, capsys, renderer):
    demos = tmp_path / "demos"
    argv = ["demos", "--task", "1", "--count", "1", "--seed", "7", "--cameras", "bottom"]
    assert cli_main([*argv, "--camera-fps", "10", "--out", str(demos)]) == 0
    sessions = sorted(p for p in demos.iterdir() if p.is_dir())
    dataset = tmp_path / "dataset"
    argv = ["export", *map(str, sessions), "--format", "lerobot", "--out", str(dataset)]
    argv += ["--task", "1", "--cameras", "bottom", "--image-size", "160x120", "--no-progress"]
    assert cli_main(argv) == 0
    policy_file = tmp_path / "vision.npz"
    assert cli_main(["learn", "vision", str(dataset), "--out", str(policy_file)]) == 0
    capsys.readouterr()

    bare = tmp_path / "no-cameras"
    argv = ["export", *map(str, sessions), "--format", "lerobot", "--out", str(bare)]
    assert cli_main([*argv, "--task", "1", "--cameras", "none", "--no-progress"]) == 0
    assert cli_main(["learn", "vision", str(bare), "--out", str(tmp_path / "no.npz")]) == 1
    assert "no bottom camera video" in capsys.readouterr().err
    other = tmp_path / "task-2"  # the same flight, exported as task 2 (A to B)
    argv = ["export", *map(str, sessions), "--format", "lerobot", "--out", str(other)]
    assert cli_main([*argv, "--task", "2", "--cameras", "none", "--no-progress"]) == 0
    assert cli_main(["learn", "vision", str(other), "--out", str(tmp_path / "no.npz")]) == 1
    assert "flies the hover (task 1)" in capsys.readouterr().err

    policy = VisionPolicy.load(policy_file)
    assert policy.task_id == 1 and policy.image_size == SIZE
    # Same time (the demonstration hovered then), attitude and state: the picture alone
    # decides. Low over the pad it climbs; at the hover height it holds.
    pad = load_scene().pad("start")
    level = _rotation(0.0, 0.0, 0.0)
    state = np.zeros(18, np.float32)
    state[9] = 1.0
    low = policy.act(_picture(renderer, [pad.x_m, pad.y_m, 2.0], level), state, 5.0)
    high = policy.act(_picture(renderer, [pad.x_m, pad.y_m, 4.0], level), state, 5.0)
    assert low[3] > high[3] + 0.3

    argv = ["learn", "eval", str(policy_file), "--task", "1", "--episodes", "2"]
    assert cli_main([*argv, "--seed", "1000", "--no-baselines"]) == 0
    rows = eval_rows(capsys.readouterr().out)
    row = rows[VisionPolicy.row_name]
    # columns: scored on, episodes, success [95%], crashes, hover distance, height dev., ...
    assert row[1] == "2" and row[2].startswith("100%") and row[3] == "0"
    assert float(row[4].split(" ")[0]) < 0.5


def test_vision_policy_files_are_checked(tmp_path: Path, capsys):
    bogus = tmp_path / "bogus.npz"
    np.savez(bogus, format=np.array("fpv-station-vision-knn-1"), inputs=np.zeros((2, 3)))
    assert cli_main(["learn", "eval", str(bogus), "--task", "1", "--episodes", "1"]) == 1
    assert "train it again" in capsys.readouterr().err
    no_video = tmp_path / "ds"
    assert cli_main(["learn", "vision", str(no_video), "--out", str(tmp_path / "p.npz")]) == 1
    assert "not a LeRobot dataset" in capsys.readouterr().err
