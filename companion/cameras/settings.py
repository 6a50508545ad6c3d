"""The cameras' settings section (`[cameras]`), composed by `server.settings`. Imports only
`spec` (no OpenCV), so settings validate without loading the capture code."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from fpv_station.companion.cameras.spec import parse_spec
from fpv_station.core.settings_section import Section, checked_by


class CameraConfig(Section):
    """One camera: its source and the picture asked of it."""

    spec: Annotated[str | None, checked_by(parse_spec)] = Field(
        None,
        description="The camera's source (companion/cameras/spec.py): v4l2:/dev/video0, "
        "v4l2:0, file:X.mp4, folder:DIR, sim:front, airsim:HOST:PORT/CAMERA, none. None: "
        "sim:<name> when link.source is sim, else none. Spec options (?width=..&fps=..) "
        "override the keys below.",
    )
    width: int = Field(640, ge=16, le=8192, description="Width asked of the camera (px).")
    height: int = Field(480, ge=16, le=8192, description="Height asked of the camera (px).")
    fps: float = Field(30.0, gt=0, le=240, description="Frames a second asked of the camera.")
    jpeg_quality: int = Field(
        80,
        ge=1,
        le=100,
        description="JPEG quality when frames are encoded here (MJPEG passes through).",
    )
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
    """The front and bottom cameras, and how a failing one is retried."""

    front: CameraConfig = Field(default_factory=CameraConfig, description="The front camera.")
    bottom: CameraConfig = Field(default_factory=CameraConfig, description="The bottom camera.")
    stall_s: float = Field(
        2.0, gt=0, description="No frame for this long (s): NO SIGNAL (stalled), and reopen."
    )
    retry_min_s: float = Field(
        0.5, gt=0, description="First reopen back-off (s), doubling up to retry_max_s."
    )
    retry_max_s: float = Field(5.0, gt=0, description="Longest reopen back-off (s).")
