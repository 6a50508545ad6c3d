"""USB MJPEG cameras where none is plugged in: `fpv-station` with cv2.VideoCapture replaced.

    python -m benchmarks.usb_mjpeg_camera serve --front v4l2:/tmp/jpegs-a --bottom v4l2:/tmp/jpegs-b

A V4L2 device path that is a folder of JPEGs opens as a USB grabber that delivers those
JPEGs, looped, at the fps asked for: the station's own V4L2 source (`companion.cameras.v4l2`)
runs unchanged, so its MJPEG passthrough (FOURCC MJPG, CAP_PROP_CONVERT_RGB off, the
driver's buffer handed over as a 1xN byte row) is what is measured. Every other capture
(files, real devices) goes to OpenCV. Only the device is simulated, at its protocol
boundary (OpenCV's VideoCapture API), as the tests do with `capture_factory`.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

_MJPG = cv2.VideoWriter.fourcc(*"MJPG")
_YUYV = cv2.VideoWriter.fourcc(*"YUYV")


class FakeMjpegGrabber:
    """A USB grabber: a frame every 1/fps s from its own clock, the newest one wins
    (CAP_PROP_BUFFERSIZE 1); read() blocks until the next frame, as VIDIOC_DQBUF does."""

    def __init__(self, folder: Path) -> None:
        self._jpegs = [p.read_bytes() for p in sorted(folder.glob("*.jp*g"))]
        size = _jpeg_size(self._jpegs[0]) if self._jpegs else (0, 0)
        self._props: dict[int, float] = {
            cv2.CAP_PROP_FOURCC: float(_YUYV),  # what a grabber starts in until asked
            cv2.CAP_PROP_FRAME_WIDTH: float(size[0]),
            cv2.CAP_PROP_FRAME_HEIGHT: float(size[1]),
            cv2.CAP_PROP_FPS: 30.0,
            cv2.CAP_PROP_CONVERT_RGB: 1.0,
            cv2.CAP_PROP_BUFFERSIZE: 4.0,
        }
        self._size = size
        self._t0: float | None = None
        self._last_index = -1
        self._open = bool(self._jpegs)

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        return self._open

    def set(self, prop: int, value: float) -> bool:
        if prop == cv2.CAP_PROP_FOURCC and int(value) not in (_MJPG, _YUYV):
            return False
        if prop in (cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT):
            return False  # one frame size: the JPEGs' own (the station keeps a device's size)
        self._props[prop] = float(value)
        return True

    def get(self, prop: int) -> float:
        return self._props.get(prop, 0.0)

    def read(self) -> tuple[bool, np.ndarray | None]:
        if not self._open:
            return False, None
        period = 1.0 / self._props[cv2.CAP_PROP_FPS]
        now = time.monotonic()
        if self._t0 is None:
            self._t0 = now
        # The next frame the device finishes after the last one handed out; a late reader
        # gets the newest (the driver dropped the ones in between).
        index = max(self._last_index + 1, int((now - self._t0) / period))
        ready_at = self._t0 + (index + 1) * period
        if ready_at > now:
            time.sleep(ready_at - now)
        self._last_index = index
        jpeg = self._jpegs[index % len(self._jpegs)]
        if (
            int(self._props[cv2.CAP_PROP_FOURCC]) == _MJPG
            and not self._props[cv2.CAP_PROP_CONVERT_RGB]
        ):
            # OpenCV copies the driver's buffer into the Mat it returns: one copy, as here.
            return True, np.frombuffer(jpeg, np.uint8).reshape(1, -1).copy()
        return True, cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)

    def release(self) -> None:
        self._open = False


def _jpeg_size(data: bytes) -> tuple[int, int]:
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ValueError("not a JPEG")
    return (image.shape[1], image.shape[0])


def install() -> None:
    """Route captures of JPEG folders to FakeMjpegGrabber; before the station imports cv2
    users (their default arguments bind cv2.VideoCapture at import)."""
    real = cv2.VideoCapture

    def video_capture(device: Any, *args: Any) -> Any:
        if isinstance(device, str) and Path(device).is_dir():
            return FakeMjpegGrabber(Path(device))
        return real(device, *args)

    # A function in place of the class: what the station's captures call.
    cv2.VideoCapture = video_capture  # type: ignore[misc,assignment]


if __name__ == "__main__":
    install()
    from fpv_station.server.cli import main

    sys.exit(main(sys.argv[1:]))
