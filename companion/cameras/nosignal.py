"""The NO SIGNAL picture a failed camera shows: its name and the reason, large and plain."""

from __future__ import annotations

import textwrap

import cv2
import numpy as np

_FONT = cv2.FONT_HERSHEY_SIMPLEX


def render_no_signal(camera: str, reason: str, width: int, height: int) -> np.ndarray:
    """A BGR image saying NO SIGNAL, the camera's name and why (wrapped to fit)."""
    image = np.full((height, width, 3), 32, np.uint8)
    # Diagonal stripes so that a frozen NO SIGNAL frame is not mistaken for a dark scene.
    yy, xx = np.mgrid[0:height, 0:width]
    image[((xx + yy) // 24) % 2 == 0] = 44
    scale = width / 640.0
    _centered(image, "NO SIGNAL", 0.38 * height, 1.6 * scale, (60, 60, 230), max(2, int(4 * scale)))
    _centered(
        image, camera.upper(), 0.52 * height, 1.0 * scale, (235, 235, 235), max(1, int(2 * scale))
    )
    chars = max(20, int(width / (11 * scale)))
    for i, line in enumerate(textwrap.wrap(reason, chars)[:4]):
        _centered(image, line, (0.64 + 0.07 * i) * height, 0.6 * scale, (200, 200, 200), 1)
    return image


def _centered(
    image: np.ndarray, text: str, y: float, scale: float, color: tuple, thick: int
) -> None:
    (w, _), _ = cv2.getTextSize(text, _FONT, scale, thick)
    x = max(4, (image.shape[1] - w) // 2)
    cv2.putText(image, text, (x, int(y)), _FONT, scale, color, thick, cv2.LINE_AA)
