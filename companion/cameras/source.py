"""The camera source interface: what every source (V4L2, file, folder, twin, AirSim) is.

A source is driven by exactly one capture thread (`companion.cameras.capture.Camera`):
`open()`, then `read()` until it raises `SourceError`, then `close()`; the thread
retries `open()` with back-off. A source never publishes anything itself.

`paced` sources (files, folders, the twin, AirSim) produce a frame whenever asked, so
the capture thread asks at the configured fps; unpaced ones (V4L2) block in `read()`
until the device delivers, and the device sets the rate.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np


class SourceError(Exception):
    """The source cannot deliver; the message is the reason shown on the NO SIGNAL frame."""


@dataclass(frozen=True, slots=True)
class SourceConfig:
    """A camera's resolved settings (spec options over the settings section)."""

    name: str
    width: int
    height: int
    fps: float
    jpeg_quality: int
    stall_s: float = 2.0
    tilt_up_deg: float | None = None  # optical axis above the nose (CameraConfig)
    vfov_deg: float | None = None  # vertical field of view, None when unknown


@dataclass(frozen=True, slots=True)
class Optics:
    """Where a camera looks and how much it sees: what a source can declare about itself."""

    tilt_up_deg: float  # optical axis above the vehicle's nose
    vfov_deg: float  # vertical field of view of the frames it delivers


@dataclass(slots=True)
class Captured:
    """One frame from a source: a BGR image to encode, or JPEG bytes to pass through."""

    image: np.ndarray | None = None  # HxWx3 uint8 BGR
    jpeg: bytes | None = None  # already a whole JPEG (MJPEG passthrough)
    width: int = 0
    height: int = 0


class FrameSource(abc.ABC):
    """One camera source; see the module docstring for the life cycle."""

    paced: bool = True
    # Whether the capture thread scales images to the configured size (a device's own
    # size is kept: passthrough JPEGs cannot be scaled without a decode).
    resize_to_config: bool = True

    def __init__(self, config: SourceConfig) -> None:
        self.config = config

    @abc.abstractmethod
    def describe(self) -> str:
        """A short human description of what this source reads."""

    @abc.abstractmethod
    def open(self) -> None:
        """Acquire the device or connection; raise SourceError with the reason on failure."""

    @abc.abstractmethod
    def read(self) -> Captured | None:
        """The next frame; None for a frame to skip (corrupt); SourceError when lost."""

    def close(self) -> None:  # noqa: B027 - optional hook: most sources hold nothing to release
        """Release what `open` acquired; must be safe to call after a failed open."""


def as_bgr(image: object, what: str) -> np.ndarray:
    """Check that `image` is an HxWx3 uint8 array (grey and BGRA are converted)."""
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8:
        raise SourceError(f"{what} gave {type(image).__name__}, not a uint8 image")
    if image.ndim == 2:
        return np.repeat(image[:, :, None], 3, axis=2)
    if image.ndim == 3 and image.shape[2] == 4:
        return np.ascontiguousarray(image[:, :, :3])
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] < 1 or image.shape[1] < 1:
        raise SourceError(f"{what} gave an image of shape {image.shape}, not HxWx3")
    return image
