"""Camera images as the exporters resize them: once, at export, to the dataset's size."""

from __future__ import annotations

import cv2
import numpy as np

JPEG_QUALITY = 90  # a resized picture re-encoded for MCAP: near the recorder's own quality


def fit_image(bgr: np.ndarray | None, size: tuple[int, int]) -> np.ndarray:
    """A BGR picture at `size` (width, height): scaled by area averaging (no aliasing when
    shrinking) if it is of another size; an undecodable one (None) is black."""
    if bgr is None:
        return np.zeros((size[1], size[0], 3), np.uint8)
    if bgr.shape[1::-1] == tuple(size):
        return bgr
    return cv2.resize(bgr, tuple(size), interpolation=cv2.INTER_AREA)


def decode_fit(jpeg: bytes, size: tuple[int, int]) -> np.ndarray:
    """A recorded JPEG decoded to BGR at `size`."""
    return fit_image(cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR), size)


def resized_jpeg(jpeg: bytes, size: tuple[int, int]) -> bytes:
    """A recorded JPEG at `size`, re-encoded; the bytes as they are if already that size."""
    bgr = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    if bgr is not None and bgr.shape[1::-1] == tuple(size):
        return jpeg
    ok, buf = cv2.imencode(".jpg", fit_image(bgr, size), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()
