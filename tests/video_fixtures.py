"""Shared by the video tests: a small twin-like renderer and image folders on disk."""

from __future__ import annotations

import threading
from pathlib import Path

import cv2
import numpy as np


class CountingRenderer:
    """Anything with `render(camera) -> BGR ndarray` and `optics(camera)` is a twin to the
    sim source; this one declares no optics."""

    def __init__(self, width: int = 320, height: int = 240) -> None:
        self.width, self.height = width, height
        self.calls: dict[str, int] = {}
        self.fail = threading.Event()  # set: render raises, as a crashed twin would
        self._lock = threading.Lock()

    def optics(self, camera: str) -> None:
        return None

    def render(self, camera: str) -> np.ndarray:
        if self.fail.is_set():
            raise RuntimeError("renderer is down")
        with self._lock:
            n = self.calls[camera] = self.calls.get(camera, 0) + 1
        image = np.zeros((self.height, self.width, 3), np.uint8)
        image[:, :, 1] = 120 if camera == "front" else 60
        cv2.putText(image, f"{camera} {n}", (10, self.height // 2), 0, 1.0, (255, 255, 255), 2)
        return image


def write_images(folder: Path, count: int, size: tuple[int, int], suffix: str = ".png") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    width, height = size
    rng = np.random.default_rng(7)
    for i in range(count):
        # Noise makes JPEGs as big as a real camera's (tens of kB), not a few hundred bytes.
        image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
        cv2.putText(image, str(i), (10, height // 2), 0, 1.0, (255, 255, 255), 2)
        cv2.imwrite(str(folder / f"{i:03d}{suffix}"), image)
    return folder
