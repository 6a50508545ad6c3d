"""The twin's cameras: things land at the pixels the camera model predicts."""

from __future__ import annotations

import numpy as np
import pytest

from fpv_station.core.scene import load_scene
from fpv_station.twin.dynamics import yaw_matrix
from fpv_station.twin.render import SKY_BGR, Renderer, project
from fpv_station.twin.runner import Twin
from fpv_station.twin.sim import Pose

SCENE = load_scene()


@pytest.fixture(scope="module")
def renderer() -> Renderer:
    return Renderer(SCENE)


def pose_at(x: float, y: float, z: float, yaw_rad: float = 0.0) -> Pose:
    return Pose(
        0.0, np.array([x, y, z]), np.zeros(3), yaw_matrix(np.array([yaw_rad]))[0], np.zeros(3)
    )


def pixel(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    u, v = np.round(uv).astype(int)
    return img[v, u].astype(int)


def close(bgr: np.ndarray, ref, tol: int = 40) -> bool:
    return bool(np.abs(bgr - np.asarray(ref, int)).max() <= tol)


def test_bottom_view_at_4m_shows_the_pad_and_its_marker(renderer: Renderer) -> None:
    pad = SCENE.pad("start")
    pose = pose_at(pad.x_m + 0.5, pad.y_m - 0.3, 4.0)  # off-centre: the pixels must move
    img = renderer.render("bottom", pose)
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8
    cam = renderer.cameras["bottom"]
    (centre, inset, outside), depth = project(
        cam,
        pose,
        np.array(
            [
                [pad.x_m, pad.y_m, 0.0],  # the H's crossbar
                [pad.x_m - 0.65, pad.y_m + 0.65, 0.0],  # inside the pad, outside the ring
                [pad.x_m - 1.2, pad.y_m, 0.0],
            ]
        ),
    )  # grass
    assert np.all(depth > 3.9)
    assert centre[0] < 320 and centre[1] > 240  # vehicle east and south of the pad
    assert close(pixel(img, centre), pad.marker_bgr)
    assert close(pixel(img, inset), pad.bgr)
    grass = pixel(img, outside)
    assert grass[1] > grass[0] and grass[1] > grass[2]
    # The marker is readable: a block of marker-coloured pixels, tens of pixels across.
    x0, y0 = np.round(centre).astype(int)
    block = img[y0 - 40 : y0 + 40, x0 - 40 : x0 + 40].astype(int)
    white = (np.abs(block - np.asarray(pad.marker_bgr)).max(axis=2) < 40).sum()
    assert white > 400


def test_landing_pad_marker_differs_from_start_pad(renderer: Renderer) -> None:
    pad = SCENE.pad("landing")
    pose = pose_at(pad.x_m, pad.y_m, 4.0)
    img = renderer.render("bottom", pose)
    (centre, ring_gap), _ = project(
        renderer.cameras["bottom"],
        pose,
        np.array([[pad.x_m, pad.y_m, 0.0], [pad.x_m, pad.y_m + 0.22, 0.0]]),
    )
    assert close(pixel(img, centre), pad.marker_bgr)  # the X crosses at the centre
    assert close(pixel(img, ring_gap), pad.bgr)  # ...but not straight north of it


def test_front_view_obstacle_pixels_and_occlusion(renderer: Renderer) -> None:
    near, far = SCENE.obstacle("obstacle 1"), SCENE.obstacle("obstacle 2")
    pose = pose_at(-15.0, 0.0, 1.5)  # heading east along the obstacle line
    img = renderer.render("front", pose)
    cam = renderer.cameras["front"]
    (face, far_centre, above, pad), depth = project(
        cam,
        pose,
        np.array(
            [
                [near.x_m - near.width_m / 2, near.y_m, 1.5],
                [far.x_m, far.y_m, 1.5],
                [near.x_m, near.y_m, near.height_m + 1.0],
                [SCENE.pad("landing").x_m, 0.0, 0.0],
            ]
        ),
    )
    assert np.all(depth > 0)
    got = pixel(img, face)
    assert got[2] > 2 * got[0] and got[2] > 2 * got[1]  # obstacle 1 is red
    hidden = pixel(img, far_centre)
    assert hidden[2] > 2 * hidden[0]  # obstacle 2 (blue) is behind obstacle 1: red wins
    assert close(pixel(img, above), SKY_BGR, 10)
    behind = pixel(img, pad)  # the landing pad lies behind obstacle 1 on this line
    assert close(behind, got, 10)


def test_front_view_sees_far_obstacle_from_the_side(renderer: Renderer) -> None:
    far = SCENE.obstacle("obstacle 2")
    pose = pose_at(0.0, -8.0, 1.5, yaw_rad=np.arctan2(8.0, 7.0))  # facing obstacle 2
    img = renderer.render("front", pose)
    (centre,), (depth,) = project(
        renderer.cameras["front"], pose, np.array([[far.x_m, far.y_m, 1.0]])
    )
    assert depth > 0 and 0 < centre[0] < 640
    got = pixel(img, centre)
    assert got[0] > 2 * got[2]  # blue


def test_horizon_follows_roll() -> None:
    no_net = SCENE.model_copy(update={"field": SCENE.field.model_copy(update={"net_height_m": 0})})
    renderer = Renderer(no_net)
    roll = np.radians(20)
    R = yaw_matrix(np.array([0.0]))[0] @ np.array(
        [[1, 0, 0], [0, np.cos(roll), -np.sin(roll)], [0, np.sin(roll), np.cos(roll)]]
    )
    pose = Pose(0.0, np.array([-25.0, 0.0, 2.0]), np.zeros(3), R, np.zeros(3))
    img = renderer.render("front", pose)
    cam = renderer.cameras["front"]
    # Two far points at the camera's height, left and right: on the horizon.
    pts = np.array([[400.0, 150.0, 2.0], [400.0, -150.0, 2.0]])
    (left, right), _ = project(cam, pose, pts)
    assert abs(left[1] - right[1]) > 50  # the horizon is tilted
    for p in (left, right):
        assert 0 < p[0] < 640
        assert close(pixel(img, p - [0, 15]), SKY_BGR, 10)
        assert not close(pixel(img, p + [0, 15]), SKY_BGR, 10)


def test_twin_render_from_live_pose_and_bad_camera() -> None:
    twin = Twin()
    twin.step_for(0.1)
    front, bottom = twin.render("front"), twin.render("bottom")
    assert front.shape == bottom.shape == (480, 640, 3)
    assert not np.array_equal(front, bottom)
    with pytest.raises(ValueError, match="front"):
        twin.render("left")


def test_any_pose_renders_without_error(renderer: Renderer) -> None:
    """Upside down, inside an obstacle, on the ground, outside the net: always a frame."""
    rng = np.random.default_rng(0)
    for k in range(150):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        w, x, y, z = q
        R = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        pos = rng.uniform([-45, -30, 0], [45, 30, 40])
        if k % 10 == 0:
            pos = np.array([-7.0, 0.0, 1.0])  # inside obstacle 1
        if k % 10 == 1:
            pos[2] = 0.0
        pose = Pose(0.0, pos, np.zeros(3), R, np.zeros(3))
        for cam in ("front", "bottom"):
            img = renderer.render(cam, pose)
            assert img.shape == (480, 640, 3) and img.dtype == np.uint8
