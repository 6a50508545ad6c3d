"""The station's cameras, built from the settings: name -> Camera, started and stopped together.

`station.cameras` is this mapping; every reader (MJPEG route, recorder) uses
`station.cameras[name].frames`, a `Latest[Frame]`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

from fpv_station.companion.cameras.airsim import AirSimSource
from fpv_station.companion.cameras.capture import Camera
from fpv_station.companion.cameras.media import ImageFolderSource, VideoFileSource
from fpv_station.companion.cameras.settings import CameraConfig
from fpv_station.companion.cameras.source import FrameSource, SourceConfig
from fpv_station.companion.cameras.spec import CameraSpec, flag, parse_spec
from fpv_station.companion.cameras.twin_cameras import Renderer, SimSource
from fpv_station.companion.cameras.v4l2 import V4l2Source

CAMERA_NAMES = ("front", "bottom")


def effective_spec(name: str, spec: str | None, link_source: str) -> str:
    """The spec a camera runs: as configured, else the twin's camera when flying the twin."""
    if spec is not None:
        return spec
    return f"sim:{name}" if link_source.strip().lower() == "sim" else "none"


def make_source(
    spec: CameraSpec, config: SourceConfig, renderer: Callable[[], Renderer | None]
) -> FrameSource | None:
    kind = spec.kind
    if kind == "none":
        return None
    if kind == "v4l2":
        return V4l2Source(config, spec.device, spec.fourcc)
    if kind == "file":
        return VideoFileSource(config, spec.target)
    if kind == "folder":
        return ImageFolderSource(config, spec.target)
    if kind == "sim":
        return SimSource(config, spec.target, renderer)
    if kind == "airsim":
        host, port, camera = spec.airsim_address
        return AirSimSource(
            config,
            host,
            port,
            camera,
            vehicle=spec.options.get("vehicle", ""),
            image_type=int(spec.options.get("image_type", "0")),
            compress=flag(spec, "compress"),
            external=flag(spec, "external"),
        )
    raise AssertionError(f"unhandled camera kind {kind}")  # parse_spec admits no other


def build_camera(
    name: str,
    cfg: CameraConfig,
    link_source: str = "none",
    renderer: Callable[[], Renderer | None] = lambda: None,
    stall_s: float = 2.0,
    retry_min_s: float = 0.5,
    retry_max_s: float = 5.0,
) -> Camera:
    spec = parse_spec(effective_spec(name, cfg.spec, link_source))
    tilt_up_deg, vfov_deg = cfg.tilt_up_deg, cfg.vfov_deg
    twin = renderer() if spec.kind == "sim" else None
    declared = twin.optics(spec.target) if twin is not None else None
    if declared is not None:  # the twin's camera declares what it renders; settings override
        tilt_up_deg = declared.tilt_up_deg if tilt_up_deg is None else tilt_up_deg
        vfov_deg = declared.vfov_deg if vfov_deg is None else vfov_deg
    config = SourceConfig(
        name=name,
        width=spec.width or cfg.width,
        height=spec.height or cfg.height,
        fps=spec.fps or cfg.fps,
        jpeg_quality=spec.quality or cfg.jpeg_quality,
        stall_s=stall_s,
        tilt_up_deg=tilt_up_deg,
        vfov_deg=vfov_deg,
    )
    return Camera(spec, config, make_source(spec, config, renderer), retry_min_s, retry_max_s)


def start_cameras(cameras: Iterable[Camera]) -> None:
    for camera in cameras:
        camera.start()


def stop_cameras(cameras: Iterable[Camera]) -> None:
    cameras = list(cameras)
    for camera in cameras:
        camera.request_stop()  # all at once, so that their shutdowns overlap
    for camera in cameras:
        camera.stop()
