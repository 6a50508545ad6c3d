"""The cameras' settings section (`[cameras]`), composed by `server.settings`. Imports only
`spec` (no OpenCV), so settings validate without loading the capture code."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from fpv_station.companion.cameras.spec import parse_spec
from fpv_station.core.settings_section import Section, checked_by


class CameraConfig(Section):
    # A camera spec (see companion/cameras/spec.py): v4l2:/dev/video0, v4l2:0, file:X.mp4,
    # folder:DIR, sim:front, airsim:HOST:PORT/CAMERA, none. None = sim:<name> when
    # link.source is "sim", else none. Spec options (?width=..&fps=..) override the rest.
    spec: Annotated[str | None, checked_by(parse_spec)] = None  # CameraSpecError says why
    width: int = Field(640, ge=16, le=8192)
    height: int = Field(480, ge=16, le=8192)
    fps: float = Field(30.0, gt=0, le=240)
    jpeg_quality: int = Field(80, ge=1, le=100)
    # The optics the OSD draws its horizon and pitch ladder with (web/osd.js).
    tilt_up_deg: float | None = Field(
        None,
        ge=-90,
        le=90,
        description="How far the camera's optical axis points above the vehicle's nose, in "
        "degrees (FPV cameras are tilted up for forward flight). None: the source's own "
        "(the twin's cameras declare theirs), else 0.",
    )
    vfov_deg: float | None = Field(
        None,
        gt=0,
        lt=180,
        description="The picture's vertical field of view, top edge to bottom edge, in "
        "degrees. None: the source's own (the twin's cameras declare theirs), else unknown "
        "(the OSD then assumes 60).",
    )


class CameraSettings(Section):
    front: CameraConfig = Field(default_factory=CameraConfig)
    bottom: CameraConfig = Field(default_factory=CameraConfig)
    stall_s: float = Field(2.0, gt=0)  # no frame for this long = NO SIGNAL (stalled)
    retry_min_s: float = Field(0.5, gt=0)  # reopen back-off, doubling up to retry_max_s
    retry_max_s: float = Field(5.0, gt=0)
