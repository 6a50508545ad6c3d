"""WGS-84 geodesy for flight tracks: geodetic -> ECEF -> local East-North-Up, and the
paper's alignment of a track so that the start-to-reference line lies along +x.

All functions are vectorized over numpy arrays (any shape, broadcast) and pure.
pymap3d does the ellipsoid math: it is small, well kept and matches the Matlab
mapping toolbox, which is what the paper's analysis used.
"""

from __future__ import annotations

import numpy as np
import pymap3d
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def geodetic_to_ecef(lat_deg: ArrayLike, lon_deg: ArrayLike, alt_m: ArrayLike) -> Array:
    """ECEF coordinates (m), stacked on the last axis as (..., 3)."""
    x, y, z = pymap3d.geodetic2ecef(
        np.asarray(lat_deg, float), np.asarray(lon_deg, float), np.asarray(alt_m, float)
    )
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def geodetic_to_enu(
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
    alt_m: ArrayLike,
    origin_lat_deg: float,
    origin_lon_deg: float,
    origin_alt_m: float,
) -> Array:
    """East-North-Up (m) about the origin, stacked on the last axis as (..., 3)."""
    e, n, u = pymap3d.geodetic2enu(
        np.asarray(lat_deg, float),
        np.asarray(lon_deg, float),
        np.asarray(alt_m, float),
        origin_lat_deg,
        origin_lon_deg,
        origin_alt_m,
    )
    return np.stack(np.broadcast_arrays(e, n, u), axis=-1)


def enu_to_geodetic(
    enu_m: ArrayLike, origin_lat_deg: float, origin_lon_deg: float, origin_alt_m: float
) -> Array:
    """Inverse of `geodetic_to_enu`: (..., 3) ENU -> (..., 3) of lat_deg, lon_deg, alt_m."""
    enu = np.asarray(enu_m, float)
    lat, lon, alt = pymap3d.enu2geodetic(
        enu[..., 0], enu[..., 1], enu[..., 2], origin_lat_deg, origin_lon_deg, origin_alt_m
    )
    return np.stack(np.broadcast_arrays(lat, lon, alt), axis=-1)


def heading_alignment_rad(start_en: ArrayLike, reference_en: ArrayLike) -> float:
    """The rotation about Up that turns the start->reference direction onto +x (east)."""
    d = np.asarray(reference_en, float)[:2] - np.asarray(start_en, float)[:2]
    if not np.any(d):
        raise ValueError("The reference point coincides with the start point; no direction.")
    return float(-np.arctan2(d[1], d[0]))


def rotate_about_up(enu_m: ArrayLike, angle_rad: float) -> Array:
    """Rotate (..., 3) points counter-clockwise about the vertical axis by `angle_rad`."""
    p = np.asarray(enu_m, float)
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    out = p.copy()
    out[..., 0] = c * p[..., 0] - s * p[..., 1]
    out[..., 1] = s * p[..., 0] + c * p[..., 1]
    return out


def track_to_aligned_enu(
    lat_deg: ArrayLike,
    lon_deg: ArrayLike,
    alt_m: ArrayLike,
    origin: tuple[float, float, float] | None = None,
    reference_latlon: tuple[float, float] | None = None,
) -> Array:
    """The paper's frame: ENU about `origin` (default: the first point of the track),
    rotated so that the line from the origin to `reference_latlon` lies along +x.

    x = longitudinal, y = lateral, z = height. Without a reference the ENU axes stay.
    """
    lat = np.asarray(lat_deg, float)
    lon = np.asarray(lon_deg, float)
    alt = np.asarray(alt_m, float)
    if origin is None:
        if lat.size == 0:
            raise ValueError("An empty track has no first point to use as origin.")
        origin = (float(lat.flat[0]), float(lon.flat[0]), float(alt.flat[0]))
    enu = geodetic_to_enu(lat, lon, alt, *origin)
    if reference_latlon is None:
        return enu
    ref = geodetic_to_enu(reference_latlon[0], reference_latlon[1], origin[2], *origin)
    return rotate_about_up(enu, heading_alignment_rad((0.0, 0.0), ref))


class LatLonError(ValueError):
    """Text that is not a `LAT,LON` pair in degrees; the message says why."""


def parse_latlon(text: str) -> tuple[float, float]:
    """`"43.0021,-78.7870"` -> (43.0021, -78.787): the one parser of a LAT,LON pair (CLI
    flags and query parameters alike)."""
    shown = text[:60]
    try:
        lat_s, lon_s = text.split(",")
        lat, lon = float(lat_s), float(lon_s)
    except ValueError:
        raise LatLonError(
            f"'{shown}' is not LAT,LON in degrees (for example 43.0021,-78.7870)."
        ) from None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180):
        raise LatLonError(f"'{shown}' is outside latitude -90..90, longitude -180..180.")
    return lat, lon
