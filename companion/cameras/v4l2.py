"""USB / V4L2 capture through OpenCV, with MJPEG passthrough.

Most USB analog-video grabbers deliver MJPEG. With CAP_PROP_CONVERT_RGB off, OpenCV's
V4L2 backend hands over the driver's buffer undecoded (a 1xN byte row); when that is a
whole JPEG its bytes go to viewers as they are: no decode, no re-encode. Devices that
deliver raw formats (YUYV) are converted by OpenCV and encoded once by the capture thread.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from fpv_station.companion.cameras.jpeg import jpeg_size, trim_jpeg
from fpv_station.companion.cameras.source import Captured, FrameSource, SourceConfig, SourceError

log = logging.getLogger(__name__)


def fourcc_text(code: float) -> str:
    value = int(code)
    text = "".join(chr((value >> (8 * i)) & 0xFF) for i in range(4))
    return text if text.isprintable() and value else "?"


class V4l2Source(FrameSource):
    paced = False  # the device sets the rate; read() blocks until it delivers
    resize_to_config = False

    def __init__(
        self,
        config: SourceConfig,
        device: str | int,
        fourcc: str | None,
        capture_factory: Callable[..., Any] = cv2.VideoCapture,
    ) -> None:
        super().__init__(config)
        self.device = device
        self._capture_factory = capture_factory  # tests stand in for the USB device here
        self.fourcc_wanted = (fourcc or "MJPG").upper()
        self.fourcc = "?"
        self.passthrough = False
        self._cap: cv2.VideoCapture | None = None

    def describe(self) -> str:
        mode = "MJPEG passthrough" if self.passthrough else f"{self.fourcc}, encoded"
        return f"V4L2 {self.device} ({mode})"

    def open(self) -> None:
        if isinstance(self.device, str) and not os.path.exists(self.device):
            raise SourceError(f"{self.device} does not exist (unplugged?)")
        cap = self._capture_factory(self.device, cv2.CAP_V4L2)
        if not cap.isOpened():
            cap.release()
            raise SourceError(
                f"cannot open {self.device} (busy, not a capture device, or no permission)"
            )
        cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc(*self.fourcc_wanted))
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.config.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.config.height)
        cap.set(cv2.CAP_PROP_FPS, self.config.fps)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # newest frame, not a queue of old ones
        # A stalled device makes read() fail after this instead of blocking forever.
        cap.set(cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(self.config.stall_s * 1000))
        self.fourcc = fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))
        self.passthrough = self.fourcc == "MJPG" and cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        self._cap = cap
        log.info("camera %s: %s", self.config.name, self.describe())

    def read(self) -> Captured | None:
        assert self._cap is not None, "read() before open()"
        ok, buf = self._cap.read()
        if not ok or buf is None:
            raise SourceError(f"{self.device} delivered no frame (unplugged or stalled)")
        if buf.ndim == 3 and buf.shape[2] == 3:  # OpenCV decoded it after all
            return Captured(image=buf, width=buf.shape[1], height=buf.shape[0])
        if self.passthrough:
            data = trim_jpeg(np.ascontiguousarray(buf).tobytes())
            size = jpeg_size(data) if data is not None else None
            if data is None or size is None:
                return None  # a truncated or corrupt frame is skipped (counted as dropped)
            return Captured(jpeg=data, width=size[0], height=size[1])
        raise SourceError(f"{self.device} delivered an unexpected buffer {buf.shape}")

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
