"""The digital twin's rendered cameras as a camera source.

Codes against a protocol, not the twin's module: any object with
`render(camera: str) -> np.ndarray` (HxWx3 uint8 BGR) will do; `twin.runner.Twin` is one.
The twin may start after the cameras or restart, so the source asks a getter for the
renderer at every open. Each frame carries its counter and render time in its top-left
corner (`frame_stamp`), from which a page measures render-to-screen latency.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol

import numpy as np

from fpv_station.companion.cameras.frame_stamp import stamp
from fpv_station.companion.cameras.source import (
    Captured,
    FrameSource,
    Optics,
    SourceConfig,
    SourceError,
    as_bgr,
)


class Renderer(Protocol):
    def render(self, camera: str) -> np.ndarray: ...

    def optics(self, camera: str) -> Optics | None:
        """The tilt and vertical field of view that `render(camera)` draws with (None: no
        such camera)."""
        ...


class SimSource(FrameSource):
    paced = True

    def __init__(
        self, config: SourceConfig, camera: str, renderer: Callable[[], Renderer | None]
    ) -> None:
        super().__init__(config)
        self.camera = camera
        self._get_renderer = renderer
        self._renderer: Renderer | None = None
        self._rendered = 0  # frames rendered, the stamp's counter

    def describe(self) -> str:
        return f"digital twin camera '{self.camera}'"

    def open(self) -> None:
        renderer = self._get_renderer()
        if renderer is None:
            raise SourceError("the digital twin is not running")
        self._renderer = renderer

    def read(self) -> Captured | None:
        assert self._renderer is not None, "read() before open()"
        try:
            image = self._renderer.render(self.camera)
        except Exception as exc:  # the twin's fault must not kill the capture thread
            raise SourceError(f"twin camera '{self.camera}' failed: {exc}") from exc
        rendered_at = time.time()
        image = as_bgr(image, f"twin camera '{self.camera}'")
        if not image.flags.writeable:
            image = image.copy()
        self._rendered += 1
        stamp(image, self._rendered, rendered_at)
        return Captured(image=image, width=image.shape[1], height=image.shape[0])

    def close(self) -> None:
        self._renderer = None
