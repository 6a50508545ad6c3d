"""The flying field's pads and obstacles, read from the twin's scene file, and placed in a
track's aligned frame so plots can draw them and the twin's obstacle contacts can be
counted.

The scene (`twin/scenes/field.toml`) gives a geodetic `[home]` and pads/obstacles in a
world frame x east, y north, z up about it. A track's frame has its own origin (the
arming point) and is rotated so start-to-reference is +x; `FieldLayout.in_track_frame`
does that conversion through latitude/longitude, so the two need not share an origin.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from analysis.errors import TrackLoadError
from analysis.geodesy import enu_to_geodetic, geodetic_to_enu, rotate_about_up

DEFAULT_SCENE = Path(__file__).resolve().parents[1] / "twin" / "scenes" / "field.toml"


@dataclass(frozen=True)
class Pad:
    name: str
    x_m: float
    y_m: float
    size_m: float = 1.5


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
        llh = enu_to_geodetic(xy, *self.home)
        moved = rotate_about_up(geodetic_to_enu(*llh.T, *origin), rotation_rad)
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


def load_scene(path: str | Path | None = None) -> FieldLayout | None:
    """The twin's scene file as a `FieldLayout`; None when no path is given and the
    default scene does not exist. A given path that cannot be read is an error."""
    p = Path(path) if path is not None else DEFAULT_SCENE
    if not p.is_file():
        if path is None:
            return None
        raise TrackLoadError(f"Scene file '{p}' does not exist.")
    try:
        data = tomllib.loads(p.read_text())
        home = data["home"]
        pads = tuple(
            Pad(str(d["name"]), float(d["x_m"]), float(d["y_m"]), float(d.get("size_m", 1.5)))
            for d in data.get("pads", [])
        )
        obstacles = tuple(
            Obstacle(
                str(d["name"]),
                float(d["x_m"]),
                float(d["y_m"]),
                float(d.get("width_m", 1.0)),
                float(d.get("depth_m", d.get("width_m", 1.0))),
                float(d["height_m"]),
                float(np.radians(d.get("yaw_deg", 0.0))),
            )
            for d in data.get("obstacles", [])
        )
        return FieldLayout(
            home=(float(home["lat_deg"]), float(home["lon_deg"]), float(home["alt_m"])),
            pads=pads,
            obstacles=obstacles,
            name=str(data.get("name", p.stem)),
        )
    except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as exc:
        raise TrackLoadError(f"Scene file '{p}' is not a usable scene: {exc!r}") from None


def obstacle_contacts(
    xyz_m: NDArray[np.float64], obstacles: tuple[Obstacle, ...], vehicle_radius_m: float
) -> int:
    """How many times the vehicle (a sphere of `vehicle_radius_m`) enters an obstacle's
    box; each entry counts once however long it stays. Obstacles in the track's frame."""
    contacts = 0
    for o in obstacles:
        c, s = np.cos(-o.yaw_rad), np.sin(-o.yaw_rad)
        dx, dy = xyz_m[:, 0] - o.x_m, xyz_m[:, 1] - o.y_m
        u, v = c * dx - s * dy, s * dx + c * dy  # in the box's own axes
        inside = (
            (np.abs(u) <= o.width_m / 2 + vehicle_radius_m)
            & (np.abs(v) <= o.depth_m / 2 + vehicle_radius_m)
            & (xyz_m[:, 2] - vehicle_radius_m <= o.height_m)
        )
        contacts += int(inside[0]) + int(np.count_nonzero(inside[1:] & ~inside[:-1]))
    return contacts
