"""The flying field as one typed model: its size, pads, obstacles and flight tasks,
loaded from a TOML scene file. The twin simulates and renders it, analysis measures
against it, the 3D panels and the pilot's map draw it; each keeps only its own view.

World frame: x east, y north, z up (m), origin at the field's centre, georeferenced at
`home`. The default scene (`core/scenes/field.toml`) is the paper's netted outdoor field
(its section on the flight tests); users edit a copy and point the `twin.scene` or
`viser.field_file` setting at it. Validation errors name the offending key.

Obstacles are upright boxes aligned with the world axes: the schema has no yaw and
refuses unknown keys (a `yaw_deg` is an error, not silently ignored), so the twin's
collisions, the analysis' contact count and every drawing agree on the same boxes.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from fpv_station.core.geodesy import geodetic_to_enu

SCENES_DIR = Path(__file__).resolve().parent / "scenes"
DEFAULT_SCENE = SCENES_DIR / "field.toml"


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Home(_Frozen):
    lat_deg: float = Field(43.0021, ge=-90, le=90)
    lon_deg: float = Field(-78.7875, ge=-180, le=180)
    alt_m: float = 180.0


class FieldArea(_Frozen):
    size_x_m: float = Field(60.0, gt=0, le=1000)
    size_y_m: float = Field(37.0, gt=0, le=1000)
    net_height_m: float = Field(8.0, ge=0)
    grass_bgr: tuple[int, int, int] = (60, 120, 70)
    outside_bgr: tuple[int, int, int] = (70, 105, 95)
    texture_px_per_m: int = Field(16, ge=2, le=64)


def bgr_to_rgb(bgr: tuple[int, int, int]) -> tuple[int, int, int]:
    """Scene colours are OpenCV's BGR (the twin renders with OpenCV); browsers and viser
    want RGB."""
    return int(bgr[2]), int(bgr[1]), int(bgr[0])


# The one default pad size: the paper's pads are about 1.5 m squares.
DEFAULT_PAD_SIZE_M = 1.5


class Pad(_Frozen):
    name: str
    x_m: float
    y_m: float
    size_m: float = Field(DEFAULT_PAD_SIZE_M, gt=0)
    marker: str = Field("H", max_length=2)
    bgr: tuple[int, int, int] = (40, 40, 40)
    marker_bgr: tuple[int, int, int] = (240, 240, 240)

    @property
    def xy_m(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m])


class Obstacle(_Frozen):
    """An upright box standing on the ground, axis-aligned with the world frame."""

    name: str
    x_m: float
    y_m: float
    width_m: float = Field(1.0, gt=0)  # along x
    depth_m: float = Field(1.0, gt=0)  # along y
    height_m: float = Field(3.0, gt=0)
    bgr: tuple[int, int, int] = (40, 60, 200)

    def corners_m(self) -> np.ndarray:
        """The 8 corners (8, 3): bottom face first, counter-clockwise seen from above."""
        hx, hy = self.width_m / 2, self.depth_m / 2
        xy = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]]) + [self.x_m, self.y_m]
        bottom = np.column_stack([xy, np.zeros(4)])
        top = np.column_stack([xy, np.full(4, self.height_m)])
        return np.vstack([bottom, top])


# How the paper scores each kind of task (analysis.tasks implements them).
TaskAnalysis = Literal["hover", "a-to-b", "obstacle", "figure8"]
# The paper's four tasks by number, for scene files that do not name their analysis.
PAPER_TASK_ANALYSIS: dict[int, TaskAnalysis] = {
    1: "hover",
    2: "a-to-b",
    3: "obstacle",
    4: "figure8",
}


class SceneWind(_Frozen):
    """The air over the field, for the twin (`twin.dynamics.Wind`): a mean wind, gusts
    and turbulence. Calm by default."""

    east_mps: float = Field(0.0, ge=-30, le=30)
    north_mps: float = Field(0.0, ge=-30, le=30)
    gust_std_mps: float = Field(0.0, ge=0, le=10)
    gust_tau_s: float = Field(2.0, gt=0)
    turbulence_std_mps: float = Field(0.0, ge=0, le=10)


class SceneStart(_Frozen):
    """Where the twin's vehicle stands at the start: the start pad's centre facing east,
    or (`random`) a seeded draw, uniform over the pad's square and over headings within
    `heading_deg` either side of east."""

    random: bool = False
    heading_deg: float = Field(180.0, ge=0, le=180)


class Task(_Frozen):
    id: int
    name: str
    start_pad: str
    end_pad: str
    altitude_m: float = Field(3.0, gt=0)
    hold_s: float = Field(0.0, ge=0)
    circle_obstacle: str | None = None
    procedure: list[str] = Field(default_factory=list)
    # How a trial of this task is scored; None: the paper's task of the same number.
    analysis: TaskAnalysis | None = None

    @property
    def analysis_task(self) -> TaskAnalysis | None:
        return self.analysis or PAPER_TASK_ANALYSIS.get(self.id)


class Scene(_Frozen):
    name: str = "unnamed"
    home: Home = Field(default_factory=Home)
    field: FieldArea = Field(default_factory=FieldArea)
    pads: list[Pad] = Field(default_factory=list)
    obstacles: list[Obstacle] = Field(default_factory=list)
    tasks: list[Task] = Field(default_factory=list)
    wind: SceneWind = Field(default_factory=SceneWind)
    start: SceneStart = Field(default_factory=SceneStart)

    @model_validator(mode="after")
    def _references_exist(self) -> Scene:
        pads = {p.name for p in self.pads}
        obstacles = {o.name for o in self.obstacles}
        for task in self.tasks:
            for pad in (task.start_pad, task.end_pad):
                if pad not in pads:
                    raise ValueError(f"task {task.id} names pad '{pad}', which is not defined")
            if task.circle_obstacle is not None and task.circle_obstacle not in obstacles:
                raise ValueError(
                    f"task {task.id} names obstacle '{task.circle_obstacle}', not defined"
                )
        if not pads:
            raise ValueError("a scene needs at least one pad (the vehicle starts on the first)")
        return self

    def pad(self, name: str) -> Pad:
        for pad in self.pads:
            if pad.name == name:
                return pad
        raise KeyError(f"No pad named '{name}' in scene '{self.name}'.")

    def obstacle(self, name: str) -> Obstacle:
        for obstacle in self.obstacles:
            if obstacle.name == name:
                return obstacle
        raise KeyError(f"No obstacle named '{name}' in scene '{self.name}'.")

    def task(self, task_id: int) -> Task:
        for task in self.tasks:
            if task.id == task_id:
                return task
        raise KeyError(f"No task {task_id} in scene '{self.name}'.")

    @property
    def home_llh(self) -> tuple[float, float, float]:
        """The world origin as (lat_deg, lon_deg, alt_m)."""
        return self.home.lat_deg, self.home.lon_deg, self.home.alt_m

    def origin_in_enu(self, origin_llh: tuple[float, float, float]) -> np.ndarray:
        """Where the field's (0, 0, 0) lies in the ENU frame about `origin_llh`."""
        return geodetic_to_enu(*self.home_llh, *origin_llh)

    @property
    def start_xy_m(self) -> np.ndarray:
        return self.pads[0].xy_m

    def obstacle_boxes_m(self) -> np.ndarray:
        """(K, 6) of x_min, y_min, z_min, x_max, y_max, z_max for vectorized collision."""
        if not self.obstacles:
            return np.zeros((0, 6))
        return np.array(
            [
                [
                    o.x_m - o.width_m / 2,
                    o.y_m - o.depth_m / 2,
                    0.0,
                    o.x_m + o.width_m / 2,
                    o.y_m + o.depth_m / 2,
                    o.height_m,
                ]
                for o in self.obstacles
            ]
        )


class SceneError(ValueError):
    """A scene file that cannot be used; the message says which file and which key."""


def load_scene(path: Path | str | None = None) -> Scene:
    """Load and validate a scene file (default: the paper's field, DEFAULT_SCENE)."""
    path = Path(path) if path is not None else DEFAULT_SCENE
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise SceneError(f"Scene file '{path}' does not exist.") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"Scene file '{path}' is not valid TOML: {exc}") from None
    try:
        return Scene.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(
            f"'{'.'.join(str(p) for p in err['loc']) or '(scene)'}': {err['msg']}"
            for err in exc.errors()
        )
        raise SceneError(f"Scene file '{path}' is invalid: {problems}") from None
