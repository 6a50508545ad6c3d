"""Vehicle pose in the scene's East-North-Up frame, and where the bottom camera looks.

MAVLink ATTITUDE gives roll, pitch, yaw of the body (Forward-Right-Down) in North-East-Down.
The scene is ENU with a Forward-Left-Up body, so
    R_enu_flu = T_enu_ned @ R_ned_frd @ T_frd_flu
with T_enu_ned swapping north/east and flipping down, T_frd_flu = diag(1, -1, -1).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

_T_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_T_FRD_FLU = np.diag([1.0, -1.0, -1.0])


def xyz(v: Array) -> tuple[float, float, float]:
    """A 3-vector as the plain floats a viser handle's position takes."""
    x, y, z = v
    return float(x), float(y), float(z)


def wxyz(q: Array) -> tuple[float, float, float, float]:
    """A quaternion as the plain floats a viser handle's orientation takes."""
    w, x, y, z = q
    return float(w), float(x), float(y), float(z)


def R_ned_frd_from_euler(roll_rad: float, pitch_rad: float, yaw_rad: float) -> Array:
    """Aerospace Z-Y-X (yaw, pitch, roll) rotation, body FRD -> world NED."""
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def R_enu_flu_from_euler(roll_rad: float, pitch_rad: float, yaw_rad: float) -> Array:
    """Rotation body FLU -> world ENU from MAVLink's roll, pitch, yaw."""
    return _T_ENU_NED @ R_ned_frd_from_euler(roll_rad, pitch_rad, yaw_rad) @ _T_FRD_FLU


def wxyz_from_matrix(R: Array) -> Array:
    """Unit quaternion (w, x, y, z) of a rotation matrix (Shepperd's method, w >= 0)."""
    m = np.asarray(R, float)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    out = np.array(q)
    out /= np.linalg.norm(out)
    return out if out[0] >= 0 else -out


def bottom_footprint_enu(
    position_enu_m: Array,
    R_enu_flu: Array,
    hfov_rad: float,
    vfov_rad: float,
    ground_up_m: float = 0.0,
    max_range_m: float = 200.0,
) -> Array | None:
    """The four ground corners (4, 3) seen by a camera looking straight down the body's -z.

    The image's vertical axis runs along the body's forward axis, so `vfov_rad` spans
    forward/back and `hfov_rad` left/right. None when the vehicle is on or under the
    ground, or a corner ray misses the ground within `max_range_m` (tilted towards the
    horizon): a footprint stretched to infinity says nothing useful.
    """
    p = np.asarray(position_enu_m, float)
    height = p[2] - ground_up_m
    if height <= 0.01:
        return None
    tx, ty = np.tan(vfov_rad / 2.0), np.tan(hfov_rad / 2.0)
    corners_flu = np.array([[tx, ty, -1.0], [tx, -ty, -1.0], [-tx, -ty, -1.0], [-tx, ty, -1.0]])
    rays_enu = corners_flu @ np.asarray(R_enu_flu, float).T
    down = -rays_enu[:, 2]
    if np.any(down <= 1e-6):
        return None
    t = height / down
    hits = p + rays_enu * t[:, None]
    if np.any(np.linalg.norm(hits - p, axis=1) > max_range_m):
        return None
    hits[:, 2] = ground_up_m
    return hits
