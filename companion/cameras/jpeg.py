"""JPEG bytes: recognise them, read their size without decoding, encode images once.

MJPEG passthrough needs to know that a buffer from a device is a whole JPEG and how big
it is, without paying for a decode; `JpegEncoder` counts its encodes and their time so
that `/api/cameras` (and the tests) can see that each frame is encoded exactly once.
"""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np

SOI = b"\xff\xd8"
EOI = b"\xff\xd9"
# Start-of-frame markers that carry the image size (baseline, extended, progressive, ...).
_SOF_MARKERS = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) of a JPEG from its SOF segment, or None if `data` is not a JPEG."""
    if len(data) < 4 or not data.startswith(SOI):
        return None
    i, n = 2, len(data)
    while i + 4 <= n:
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01,) or 0xD0 <= marker <= 0xD7:  # markers without a length
            i += 2
            continue
        length = int.from_bytes(data[i + 2 : i + 4], "big")
        if marker in _SOF_MARKERS:
            if i + 9 > n:
                return None
            height = int.from_bytes(data[i + 5 : i + 7], "big")
            width = int.from_bytes(data[i + 7 : i + 9], "big")
            return (width, height) if width and height else None
        if marker == 0xDA:  # start of scan before any SOF: not a usable JPEG
            return None
        i += 2 + length
    return None


def trim_jpeg(data: bytes) -> bytes | None:
    """A device buffer cut to its JPEG (drivers may pad after EOI); None if it is no JPEG."""
    if not data.startswith(SOI):
        return None
    end = data.rfind(EOI)
    if end < 0:
        return None  # truncated frame: the decoder would show grey blocks
    return data[: end + 2]


class JpegEncoder:
    """Encodes BGR images to JPEG at one quality; counts encodes and their duration."""

    def __init__(self, quality: int) -> None:
        self.quality = int(quality)
        self._params = [int(cv2.IMWRITE_JPEG_QUALITY), self.quality]
        self._lock = threading.Lock()
        self.encodes = 0
        self.last_encode_s = 0.0
        self.recent_encode_s = 0.0  # moving average over about the last 20 encodes

    def encode(self, image: np.ndarray) -> bytes:
        t0 = time.perf_counter()
        ok, buf = cv2.imencode(".jpg", image, self._params)
        dt = time.perf_counter() - t0
        if not ok:
            raise ValueError(f"OpenCV could not encode a {image.shape} {image.dtype} image")
        with self._lock:
            self.encodes += 1
            self.last_encode_s = dt
            alpha = max(0.05, 1.0 / self.encodes)
            self.recent_encode_s += alpha * (dt - self.recent_encode_s)
        return buf.tobytes()

    @property
    def recent_encode_ms(self) -> float:
        """Encode time now (moving average), what /api/cameras shows."""
        return 1000.0 * self.recent_encode_s
