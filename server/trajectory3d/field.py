"""The test field as the 3D panel draws it: a flat ground with pads and obstacles,
taken from the twin's scene file (twin/scenes/field.toml, or another one).

Coordinates are metres in the field's own frame (x east, y north, z up) about a
georeferenced anchor, so that the field lands at the right place in a flight's ENU frame
whatever the flight's origin (the arming point) is.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.geodesy import geodetic_to_enu
from twin.scene import Scene, load_scene


@dataclass(frozen=True, slots=True)
class Pad:
    name: str
    x_m: float
    y_m: float
    size_m: float = 2.0
    rgb: tuple[int, int, int] = (40, 120, 220)


@dataclass(frozen=True, slots=True)
class Obstacle:
    name: str
    x_m: float
    y_m: float
    width_m: float = 1.0  # along x
    depth_m: float = 1.0  # along y
    height_m: float = 3.0
    rgb: tuple[int, int, int] = (200, 90, 40)


@dataclass(frozen=True, slots=True)
class FieldScene:
    """The field: its size, its anchor on the globe, and what stands on it."""

    size_x_m: float
    size_y_m: float
    anchor_lat_deg: float
    anchor_lon_deg: float
    anchor_alt_m: float  # ground level (MSL) at the anchor
    pads: tuple[Pad, ...] = field(default_factory=tuple)
    obstacles: tuple[Obstacle, ...] = field(default_factory=tuple)

    def anchor_in_enu(self, origin: tuple[float, float, float]) -> np.ndarray:
        """Where the field's (0, 0, 0) lies in the ENU frame about `origin` (lat, lon, alt)."""
        return geodetic_to_enu(self.anchor_lat_deg, self.anchor_lon_deg, self.anchor_alt_m, *origin)


def field_from_scene(scene: Scene) -> FieldScene:
    """The twin's scene (twin/scenes/*.toml) as the panel draws it; its world origin (the
    field's centre) is the anchor, x east, y north, as in the twin."""
    bgr_to_rgb = lambda bgr: (int(bgr[2]), int(bgr[1]), int(bgr[0]))  # noqa: E731
    return FieldScene(
        size_x_m=scene.field.size_x_m,
        size_y_m=scene.field.size_y_m,
        anchor_lat_deg=scene.home.lat_deg,
        anchor_lon_deg=scene.home.lon_deg,
        anchor_alt_m=scene.home.alt_m,
        pads=tuple(Pad(p.name, p.x_m, p.y_m, p.size_m, bgr_to_rgb(p.bgr)) for p in scene.pads),
        obstacles=tuple(
            Obstacle(o.name, o.x_m, o.y_m, o.width_m, o.depth_m, o.height_m, bgr_to_rgb(o.bgr))
            for o in scene.obstacles
        ),
    )


def load_field(scene_file: Path | str | None = None) -> FieldScene:
    """The field of a twin scene file (None: the twin's built-in field of the paper).
    Raises twin.scene.SceneError with the file and key when the file cannot be used."""
    return field_from_scene(load_scene(scene_file))


def default_field() -> FieldScene:
    """The twin's built-in field: 60 m x 37 m, start and landing pads at x = -20 m and
    +20 m, two 3 m obstacles at x = -7 m and +7 m on y = 0, centred near 43.0021 N."""
    return load_field(None)
