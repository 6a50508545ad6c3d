"""Colour-coding of the trail: a value per point mapped onto a fixed colour ramp.

The range is fixed by the settings (not the data seen so far) so that segments already
sent keep their colour; only a change of the coding re-colours the whole trail.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

ColorBy = Literal["height", "speed"]
COLOR_BY_CHOICES: tuple[ColorBy, ...] = ("height", "speed")

# A perceptually ordered ramp (dark blue -> cyan -> green -> yellow -> red), readable on
# a light ground grid; five stops interpolated linearly.
_STOPS = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
_RGB = np.array(
    [[48, 18, 160], [30, 150, 230], [40, 190, 90], [240, 200, 30], [220, 40, 30]], float
)


def ramp_rgb(values: ArrayLike, lo: float, hi: float) -> NDArray[np.uint8]:
    """RGB (..., 3) uint8 for `values` clipped to [lo, hi]; NaN maps to grey."""
    v = np.asarray(values, float)
    span = hi - lo if hi > lo else 1.0
    u = np.clip((v - lo) / span, 0.0, 1.0)
    out = np.stack([np.interp(u, _STOPS, _RGB[:, c]) for c in range(3)], axis=-1)
    out[np.isnan(v)] = (128, 128, 128)
    return np.round(out).astype(np.uint8)


def ramp_hex(values: ArrayLike, lo: float, hi: float) -> list[str]:
    """`ramp_rgb` as CSS colours ("#rrggbb"), for pages that draw with the same ramp."""
    return [f"#{r:02x}{g:02x}{b:02x}" for r, g, b in ramp_rgb(values, lo, hi).tolist()]
