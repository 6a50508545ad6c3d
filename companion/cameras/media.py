"""Recorded media as a camera, looped at the camera's fps: a video file or an image folder.

For demos and tests. A folder of JPEGs already at the camera's size is passed through
without a decode; anything else is decoded here and encoded once by the capture thread.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from fpv_station.companion.cameras.jpeg import jpeg_size
from fpv_station.companion.cameras.source import Captured, FrameSource, SourceConfig, SourceError
from fpv_station.companion.cameras.spec import IMAGE_SUFFIXES


class VideoFileSource(FrameSource):
    paced = True

    def __init__(self, config: SourceConfig, path: str) -> None:
        super().__init__(config)
        self.path = Path(path).expanduser()
        self._cap: cv2.VideoCapture | None = None
        self._frames_read = 0

    def describe(self) -> str:
        return f"video file {self.path} (looped)"

    def open(self) -> None:
        if not self.path.is_file():
            raise SourceError(f"video file {self.path} is missing")
        cap = cv2.VideoCapture(str(self.path))
        if not cap.isOpened():
            cap.release()
            raise SourceError(f"OpenCV cannot open video file {self.path.name}")
        self._cap = cap
        self._frames_read = 0

    def read(self) -> Captured | None:
        assert self._cap is not None, "read() before open()"
        ok, image = self._cap.read()
        if not ok:
            if self._frames_read == 0:
                raise SourceError(f"video file {self.path.name} has no readable frame")
            # End of file: rewind (re-open: seeking is unreliable on some containers).
            self._cap.release()
            self.open()
            ok, image = self._cap.read()
            if not ok:
                raise SourceError(f"video file {self.path.name} could not be rewound")
        self._frames_read += 1
        return Captured(image=image, width=image.shape[1], height=image.shape[0])

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


class ImageFolderSource(FrameSource):
    paced = True

    def __init__(self, config: SourceConfig, path: str) -> None:
        super().__init__(config)
        self.path = Path(path).expanduser()
        self._files: list[Path] = []
        self._index = 0

    def describe(self) -> str:
        return f"image folder {self.path} ({len(self._files)} images, looped)"

    def open(self) -> None:
        try:
            files = sorted(p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        except OSError as exc:
            raise SourceError(f"cannot list folder {self.path}: {exc.strerror}") from None
        if not files:
            raise SourceError(f"folder {self.path} holds no images")
        self._files = files
        self._index = 0

    def read(self) -> Captured | None:
        path = self._files[self._index]
        self._index = (self._index + 1) % len(self._files)
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise SourceError(f"cannot read {path.name}: {exc.strerror}") from None
        size = jpeg_size(data)
        if size == (self.config.width, self.config.height):
            return Captured(jpeg=data, width=size[0], height=size[1])
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            return None  # one unreadable image is skipped, not fatal
        return Captured(image=image, width=image.shape[1], height=image.shape[0])
