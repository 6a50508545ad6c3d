"""Analysis' view of the field (`core.scene`): pads and obstacles placed in a track's
aligned frame so that plots can draw them and the twin's obstacle contacts can be counted.

The scene gives a geodetic `home` and pads/obstacles in a world frame x east, y north,
z up about it. A track's frame has its own origin (the arming point) and is rotated so
start-to-reference is +x; `FieldLayout.in_track_frame` does that conversion through
latitude/longitude, so the two need not share an origin. `Obstacle.yaw_rad` is that
rotation (scene obstacles are axis-aligned in the scene's frame).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from fpv_station.analysis.errors import TrackLoadError
from fpv_station.core.geodesy import enu_to_geodetic, geodetic_to_enu, rotate_about_up
from fpv_station.core.scene import DEFAULT_PAD_SIZE_M, Scene, SceneError, load_scene


@dataclass(frozen=True)
class Pad:
    name: str
    x_m: float
    y_m: float
    size_m: float = DEFAULT_PAD_SIZE_M


@dataclass(frozen=True)
class Obstacle:
    name: str
    x_m: float
    y_m: float
    width_m: float  # along the frame's x (before rotation into a track frame)
    depth_m: float
    height_m: float
    yaw_rad: float = 0.0  # the box's rotation about Up in the frame it is expressed in


@dataclass(frozen=True)
class FieldLayout:
    home: tuple[float, float, float]  # lat_deg, lon_deg, alt_m of the frame's origin
    pads: tuple[Pad, ...] = ()
    obstacles: tuple[Obstacle, ...] = ()
    name: str = "field"

    def pad(self, name: str) -> Pad | None:
        return next((p for p in self.pads if p.name == name), None)

    def pad_latlon(self, name: str) -> tuple[float, float] | None:
        p = self.pad(name)
        if p is None:
            return None
        lat, lon, _ = enu_to_geodetic([p.x_m, p.y_m, 0.0], *self.home)
        return float(lat), float(lon)

    def in_track_frame(
        self, origin: tuple[float, float, float], rotation_rad: float
    ) -> FieldLayout:
        """The same layout about `origin`, rotated by `rotation_rad` about Up (the
        track's alignment), heights still above the scene's ground. The ENU axes of two
        origins a field apart differ by ~1e-5 rad (meridian convergence): ignored."""
        xy = np.array(
            [[p.x_m, p.y_m, 0.0] for p in self.pads]
            + [[o.x_m, o.y_m, 0.0] for o in self.obstacles],
            float,
        ).reshape(-1, 3)
        lat, lon, alt = enu_to_geodetic(xy, *self.home).T
        moved = rotate_about_up(geodetic_to_enu(lat, lon, alt, *origin), rotation_rad)
        pads = tuple(
            replace(p, x_m=float(moved[i, 0]), y_m=float(moved[i, 1]))
            for i, p in enumerate(self.pads)
        )
        k = len(self.pads)
        obstacles = tuple(
            replace(
                o,
                x_m=float(moved[k + i, 0]),
                y_m=float(moved[k + i, 1]),
                yaw_rad=o.yaw_rad + rotation_rad,
            )
            for i, o in enumerate(self.obstacles)
        )
        return FieldLayout(home=origin, pads=pads, obstacles=obstacles, name=self.name)


def layout_from_scene(scene: Scene) -> FieldLayout:
    """The scene as analysis measures against it, in the scene's own world frame."""
    return FieldLayout(
        home=scene.home_llh,
        pads=tuple(Pad(p.name, p.x_m, p.y_m, p.size_m) for p in scene.pads),
        obstacles=tuple(
            Obstacle(o.name, o.x_m, o.y_m, o.width_m, o.depth_m, o.height_m)
            for o in scene.obstacles
        ),
        name=scene.name,
    )


def load_field_layout(path: str | Path | None = None) -> FieldLayout:
    """A scene file (None: the default field, core.scene.DEFAULT_SCENE) as a
    `FieldLayout`; a file that cannot be used is a TrackLoadError naming file and key."""
    try:
        return layout_from_scene(load_scene(path))
    except SceneError as exc:
        raise TrackLoadError(str(exc)) from None


def obstacle_contacts(
    xyz_m: NDArray[np.float64],
    obstacles: tuple[Obstacle, ...],
    vehicle_radius_m: float,
    margin_m: float | NDArray[np.float64] = 0.0,
) -> int:
    """How many times the vehicle (a sphere of `vehicle_radius_m`) enters an obstacle's
    box; each entry counts once however long it stays. Obstacles in the track's frame.

    `margin_m` (one value, or one per sample): how far the measured position may be
    from the true one horizontally. A positive margin counts only entries that hold
    wherever in that margin the vehicle truly was (certain contacts); a negative one,
    entries that could have happened (possible contacts)."""
    contacts = 0
    for o in obstacles:
        c, s = np.cos(-o.yaw_rad), np.sin(-o.yaw_rad)
        dx, dy = xyz_m[:, 0] - o.x_m, xyz_m[:, 1] - o.y_m
        u, v = c * dx - s * dy, s * dx + c * dy  # in the box's own axes
        reach = vehicle_radius_m - np.asarray(margin_m, dtype=np.float64)
        inside = (
            (np.abs(u) <= o.width_m / 2 + reach)
            & (np.abs(v) <= o.depth_m / 2 + reach)
            & (xyz_m[:, 2] - vehicle_radius_m <= o.height_m)
        )
        contacts += int(inside[0]) + int(np.count_nonzero(inside[1:] & ~inside[:-1]))
    return contacts
