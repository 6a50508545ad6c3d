"""A vision policy: the pilot's sticks from the bottom camera's picture and the attitude,
with no position input, trained on a LeRobot dataset exported with the bottom camera.

What it reads, per control step:
- the bottom camera's picture (RGB, any size; the dataset's at evaluation);
- the attitude: roll, pitch, sin and cos of the heading (ATTITUDE, as the OSD shows it);
- on the ground, and the time since arming (when the 10 s hover is over).
Nothing from GPS, the barometer or the distance to the target: no position, velocity
or height input. The pad, seen from above, tells where the vehicle is, as it tells the
paper's pilots in the bottom view.

Image features (`pad_view`): the pad is the grey-and-white patch on the green grass;
each pixel counts as pad by how little colour it has (`PAD_SPREAD`, `GRASS_SPREAD`),
giving the pad's area, its centroid and whether it touches the picture's edge. With the
attitude and the bottom camera's geometry (`twin.render.bottom_camera`: straight down,
90 degrees wide) they become where the vehicle is over the pad (`pad_features`): the
height from the pad's apparent size (the pad's side is known to the pilot: the scene's),
the offset east and north from the centroid's ray turned level by roll, pitch and
heading. Below about 1.2 m the pad fills the picture: the height reads as that floor,
and on the ground and the time since arming tell the take-off from the landing.

The learner is the behaviour clone's (`learn.bc`): scikit-learn's k-nearest
neighbours over these features, each divided by a fixed physical scale, and the
demonstrated sticks. A policy file is an `.npz` of plain arrays (no pickle).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import av
import numpy as np
import pyarrow.parquet as pq
from numpy.typing import NDArray

from fpv_station.core.scene import Scene, load_scene
from fpv_station.learn.bc import DEFAULT_K, Neighbours, load_arrays, read_rows, save_arrays
from fpv_station.learn.lerobot import VIDEO_PATH, read_meta, video_key
from fpv_station.twin.render import CameraModel, Renderer, bottom_camera

FORMAT = "fpv-station-vision-knn-1"
CAMERA = "bottom"
# The state elements the policy reads (`twin.gym_env.STATE_NAMES`): roll, pitch, sin and
# cos of the heading, on the ground. Position, velocity and distances are never read.
ATTITUDE = (6, 7, 8, 9, 15)
# Inputs: east, north of the pad (m), height (m), sin, cos heading, on the ground, time
# since arming (s); one unit of distance per input, as the clone's scales.
INPUT_NAMES = ("east_m", "north_m", "height_m", "sin_heading", "cos_heading", "on_ground", "t_s")
SCALES = (1.0, 1.0, 0.5, 0.2, 0.2, 1.0, 2.0)
# How much of a pixel is pad, from the spread of its R, G and B (max - min): the pad's
# grey and white have none, the grass ~60 (BGR 60, 120, 70); a pixel that is part pad,
# part grass lies between. Pad share 1 at a spread up to PAD_SPREAD, 0 from GRASS_SPREAD
# on, linear between: centred on the half-and-half pixel, so the pad's area summed over
# its blurred edge (resizing, JPEG, H.264's halved colour) stays the same.
PAD_SPREAD, GRASS_SPREAD = 15.0, 45.0
MIN_PAD_AREA_PX = 4.0  # less: the pad is not in view
OUT_OF_VIEW_M = 10.0


@dataclass(frozen=True)
class PadView:
    """What the bottom picture shows of the pad, in the camera's normalized image plane
    (x right, y down, units of the focal length: tan of the angle off the axis)."""

    visible: bool
    x: float  # the pad's centroid
    y: float
    area: float  # the pad's area (focal lengths squared)
    clipped: bool  # the pad touches the picture's edge (it does not all show)


def pad_view(rgb: NDArray[np.uint8], hfov_deg: float) -> PadView:
    """The pad in a bottom picture (H, W, 3): the area and centroid of its pixels, each
    weighted by how much of it is pad (`PAD_SPREAD`, `GRASS_SPREAD`)."""
    img = np.asarray(rgb)
    h, w = img.shape[:2]
    spread = img.max(axis=2).astype(np.float32) - img.min(axis=2)
    share = np.clip((GRASS_SPREAD - spread) / (GRASS_SPREAD - PAD_SPREAD), 0.0, 1.0)
    n = float(share.sum())
    if n < MIN_PAD_AREA_PX:
        return PadView(False, 0.0, 0.0, 0.0, False)
    f = (w / 2) / np.tan(np.radians(hfov_deg) / 2)
    u = float(share.sum(axis=0) @ (np.arange(w) + 0.5)) / n
    v = float(share.sum(axis=1) @ (np.arange(h) + 0.5)) / n
    edge = max(share[0].max(), share[-1].max(), share[:, 0].max(), share[:, -1].max())
    return PadView(True, (u - w / 2) / f, (v - h / 2) / f, n / (f * f), bool(edge >= 0.5))


def world_from_attitude(roll: float, pitch: float, sin_h: float, cos_h: float) -> np.ndarray:
    """R_world_body (ENU world, FLU body) from MAVLink's roll and pitch (NED/FRD) and the
    heading counter-clockwise from east, as `twin.gym_env` reports them."""
    yaw_ned = np.pi / 2 - np.arctan2(sin_h, cos_h)
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw_ned), np.sin(yaw_ned)
    R_ned_frd = (
        np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
        @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
        @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    )
    enu_ned = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    return enu_ned @ R_ned_frd @ np.diag([1.0, -1.0, -1.0])


def pad_features(
    view: PadView, R_world_body: np.ndarray, pad_size_m: float, camera: CameraModel
) -> tuple[float, float, float]:
    """(east, north, height) of the vehicle over the pad's centre as the picture and the
    attitude tell it. Not in view: (0, 0, nan)."""
    if not view.visible:
        return 0.0, 0.0, float("nan")
    R_wc = R_world_body @ camera.R_body_cam
    ray = R_wc @ np.array([view.x, view.y, 1.0])  # to the pad's centre, image-plane length
    down = max(-float(ray[2]), 0.05)
    # A ground patch of area a at height h shows as a (cos i / cos o)^3 / h^2 in the
    # image plane (i: the ray's angle from the vertical, o: from the optical axis);
    # cos i / cos o is the ray's downward component here.
    h_cam = pad_size_m / np.sqrt(view.area) * down**1.5
    to_pad = ray * (h_cam / down)
    height = h_cam - float((R_world_body @ camera.offset_body_m)[2])
    return float(-to_pad[0]), float(-to_pad[1]), height


def inputs_of(
    view: PadView, state: np.ndarray, t_s: float, pad_size_m: float, camera: CameraModel
) -> np.ndarray:
    """The policy's input row: the pad's features and the attitude (state elements
    `ATTITUDE` only), and the time since arming. The pad out of view reads as
    `OUT_OF_VIEW_M` up over its centre (the neighbours' distances need numbers)."""
    roll, pitch, sin_h, cos_h, on_ground = (float(state[i]) for i in ATTITUDE)
    R = world_from_attitude(roll, pitch, sin_h, cos_h)
    east, north, height = pad_features(view, R, pad_size_m, camera)
    if not view.visible:
        height = OUT_OF_VIEW_M
    return np.array([east, north, height, sin_h, cos_h, on_ground, t_s], np.float64)


@dataclass
class VisionPolicy:
    inputs: NDArray[np.float32]  # (n, len(INPUT_NAMES))
    sticks: NDArray[np.float32]  # (n, 4)
    image_size: tuple[int, int]  # (width, height) of the dataset's bottom pictures
    pad_size_m: float  # the side of the task's start pad
    k: int = DEFAULT_K
    task_id: int = 0
    hfov_deg: float = 90.0  # the bottom camera's horizontal field of view

    # `learn eval`'s name for this policy's row.
    row_name = "vision (bottom camera + attitude)"

    def __post_init__(self) -> None:
        self.camera = bottom_camera(self.hfov_deg)
        self._model = Neighbours(self.inputs, self.sticks, self.k, SCALES)
        self._renderer: Renderer | None = None

    def act(self, rgb: NDArray[np.uint8], state: np.ndarray, t_s: float) -> np.ndarray:
        """The sticks for a bottom picture (RGB), the state vector (only its attitude
        elements `ATTITUDE` are read) and the time since arming."""
        view = pad_view(rgb, self.hfov_deg)
        return self._model.sticks(inputs_of(view, state, t_s, self.pad_size_m, self.camera))

    def twin_act(self, scene: Scene) -> Callable[[np.ndarray, dict], np.ndarray]:
        """A `learn.evaluate` actor: the twin's bottom camera rendered from the vehicle's
        pose (its true position and the observed attitude) and resized to the dataset's
        size as the exporters resize (`learn.images.fit_image`), then `act`. The policy
        itself sees the picture and the attitude only."""
        from fpv_station.learn.images import fit_image
        from fpv_station.twin.sim import Pose

        if self._renderer is None or self._renderer.scene != scene:  # one per scene
            self._renderer = Renderer(scene, bottom=self.camera)
        renderer = self._renderer
        zero = np.zeros(3)

        def act(obs: np.ndarray, info: dict) -> np.ndarray:
            roll, pitch, sin_h, cos_h, _ = (float(obs[i]) for i in ATTITUDE)
            R = world_from_attitude(roll, pitch, sin_h, cos_h)
            pose = Pose(float(info["t_s"]), np.asarray(info["pos_enu_m"], float), zero, R, zero)
            bgr = fit_image(renderer.render(CAMERA, pose), self.image_size)
            return self.act(bgr[..., ::-1], obs, float(info["t_s"]))

        return act

    def save(self, path: Path) -> Path:
        return save_arrays(
            path,
            FORMAT,
            input_names=np.array(INPUT_NAMES),
            scales=np.array(SCALES),
            inputs=self.inputs,
            sticks=self.sticks,
            image_size=np.array(self.image_size),
            pad_size_m=np.array(self.pad_size_m),
            hfov_deg=np.array(self.hfov_deg),
            k=np.array(self.k),
            task_id=np.array(self.task_id),
        )

    @classmethod
    def load(cls, path: Path) -> VisionPolicy:
        names = ("input_names", "scales", "image_size", "pad_size_m", "hfov_deg")
        z = load_arrays(path, FORMAT, "vision policy", names)
        if tuple(z["input_names"].tolist()) != INPUT_NAMES or tuple(z["scales"].tolist()) != SCALES:
            raise ValueError(f"'{path}' reads other inputs; train it again")
        w, h = (int(v) for v in z["image_size"])
        return cls(
            inputs=z["inputs"],
            sticks=z["sticks"],
            image_size=(w, h),
            pad_size_m=float(z["pad_size_m"]),
            k=int(z["k"]),
            task_id=int(z["task_id"]),
            hfov_deg=float(z["hfov_deg"]),
        )


def is_vision_policy(path: Path) -> bool:
    """Whether `path` is a vision policy file (read without running anything in it)."""
    try:
        with np.load(Path(path), allow_pickle=False) as z:
            return "format" in z and str(z["format"]) == FORMAT
    except (OSError, ValueError):
        return False


def read_views(root: Path, t_s: np.ndarray, episode: np.ndarray, hfov_deg: float):
    """Per dataset row (`learn.bc.read_rows`), the `PadView` of its bottom picture, and
    the pictures' (width, height). Each video file is decoded once; a row's picture is
    the frame at `from_timestamp + timestamp` of its episode."""
    root = Path(root)
    meta = read_meta(root)
    key = video_key(CAMERA)
    feature = meta.features.get(key)
    if not feature or feature.get("dtype") != "video":
        raise ValueError(
            f"'{root}' has no bottom camera video ({key}); export it with the bottom camera"
        )
    h, w = (int(v) for v in feature["shape"][:2])
    fps = float(meta.fps)
    cols = [
        "episode_index",
        f"videos/{key}/chunk_index",
        f"videos/{key}/file_index",
        f"videos/{key}/from_timestamp",
    ]
    where: dict[int, tuple[int, int, float]] = {}  # episode -> chunk, file, from_timestamp
    for f in sorted((root / "meta" / "episodes").glob("*/*.parquet")):
        m = pq.read_table(f, columns=cols).to_pydict()
        for e, chunk, file, t0 in zip(*(m[c] for c in cols)):
            where[int(e)] = (int(chunk), int(file), float(t0))
    missing = set(np.unique(episode).tolist()) - set(where)
    if missing:
        raise ValueError(f"'{root}': episodes {sorted(missing)} have no bottom video")
    views: list[PadView] = []
    decoded: dict[tuple[int, int], dict[int, PadView]] = {}
    for t, e in zip(t_s, episode):
        chunk, file, t0 = where[int(e)]
        if (chunk, file) not in decoded:
            path = root / VIDEO_PATH.format(video_key=key, chunk_index=chunk, file_index=file)
            decoded[(chunk, file)] = _decode_views(path, fps, hfov_deg)
        frames = decoded[(chunk, file)]
        k = int(round((t0 + float(t)) * fps))
        if k not in frames:
            raise ValueError(f"'{root}': no bottom video frame at {t0 + float(t):.2f} s")
        views.append(frames[k])
    return views, (w, h)


def _decode_views(path: Path, fps: float, hfov_deg: float) -> dict[int, PadView]:
    """Frame number (time x fps) -> its `PadView`, for every frame of one video file."""
    out = {}
    with av.open(str(path)) as c:
        for frame in c.decode(video=0):
            rgb = np.asarray(frame.to_ndarray(format="rgb24"), np.uint8)
            out[int(round(frame.time * fps))] = pad_view(rgb, hfov_deg)
    return out


def train(dataset: Path, k: int = DEFAULT_K, scene: Scene | None = None) -> VisionPolicy:
    """A vision policy from a LeRobot dataset exported with the bottom camera, of a
    hover task (task 1: the pad stays under the vehicle) over a colourless pad (grey and
    white, as `pad_view` finds it); the pad's size is the scene's."""
    rows = read_rows(dataset)
    if len(rows.t_s) < 2:
        raise ValueError(f"'{dataset}' has {len(rows.t_s)} frames; a policy needs more")
    if rows.task_id == 0:
        raise ValueError(f"'{dataset}' does not say its task (export it with --task N)")
    scene = scene or load_scene()
    task = scene.task(rows.task_id)
    pad = scene.pad(task.end_pad)
    if task.analysis_task != "hover" or task.start_pad != task.end_pad:
        raise ValueError(
            f"'{dataset}' is task {task.id} ({task.name}); the vision policy flies the hover "
            "(task 1), where the pad stays in the bottom view"
        )
    if max(pad.bgr) - min(pad.bgr) >= PAD_SPREAD:
        raise ValueError(
            f"pad '{pad.name}' is coloured {pad.bgr}; the vision policy finds grey pads"
        )
    camera = bottom_camera()
    views, size = read_views(dataset, rows.t_s, rows.episode, camera.hfov_deg)
    inputs = np.stack(
        [inputs_of(v, s, t, pad.size_m, camera) for v, s, t in zip(views, rows.state, rows.t_s)]
    ).astype(np.float32)
    return VisionPolicy(inputs, rows.action, size, pad.size_m, k, rows.task_id, camera.hfov_deg)
