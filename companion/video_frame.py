"""A video frame (one JPEG of one camera) as every part of the station shares it: encoded
once, read by many. Not a coordinate frame: that is `analysis.flight_frame`."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Frame:
    """One JPEG-encoded frame of one camera.

    The same bytes go to every MJPEG viewer and to the recorder (no re-encode).
    `seq` grows by one per captured frame of that camera; `t_mono` (time.monotonic)
    orders and synchronizes streams; `t_wall` (Unix seconds) is for people and files.
    """

    camera: str
    seq: int
    jpeg: bytes
    width: int
    height: int
    t_mono: float
    t_wall: float
    signal: bool = True  # False for the NO SIGNAL placeholder of a failed camera
