"""The test field as the 3D panel draws it: a flat ground with pads and obstacles.

Coordinates are metres in the field's own frame (x east, y north, z up) about a
georeferenced anchor, so that the field lands at the right place in a flight's ENU frame
whatever the flight's origin (the arming point) is.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from analysis.geodesy import geodetic_to_enu


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
        return geodetic_to_enu(
            self.anchor_lat_deg, self.anchor_lon_deg, self.anchor_alt_m, *origin
        )


def default_field() -> FieldScene:
    """The university's netted field as the mission describes it (60 m x 37 m, two pads,
    two 3 m obstacles on the line y = 0), anchored at its centre."""
    return FieldScene(
        size_x_m=60.0,
        size_y_m=37.0,
        anchor_lat_deg=43.0021,
        anchor_lon_deg=-78.7875,
        anchor_alt_m=180.0,
        pads=(
            Pad("start", -20.0, 0.0, 2.0, (40, 120, 220)),
            Pad("landing", 20.0, 0.0, 2.0, (40, 180, 80)),
        ),
        obstacles=(Obstacle("west", -7.0, 0.0), Obstacle("east", 7.0, 0.0)),
    )
