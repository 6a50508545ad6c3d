"""Video: MJPEG streams, the newest frame, and the cameras' figures.

    GET /video/{camera}.mjpg   multipart/x-mixed-replace, one part per frame
    GET /video/{camera}.jpg    the newest frame
    GET /api/cameras           per camera: source, resolution, fps, drops, encode time, clients

Every viewer is an async generator awaiting the camera's `Latest[Frame]`: no thread per
viewer and no queue. A viewer that cannot keep up sits in its socket write; when that
returns it takes the newest frame, skipping the ones it missed, so it never delays the
camera or another viewer. Each frame's multipart part is built once and shared.
"""

from __future__ import annotations

import time
import weakref
from collections.abc import AsyncIterator

from fastapi import APIRouter, Request
from fastapi.responses import Response, StreamingResponse
from pydantic import BaseModel

from companion.frames import Frame
from companion.latest import Versioned
from server.errors import NotFound, Unavailable

router = APIRouter(tags=["video"])

BOUNDARY = "fpvframe"
_NO_CACHE = {"Cache-Control": "no-store, no-cache, must-revalidate", "Pragma": "no-cache"}
_IDLE_WAIT_S = 5.0  # wake up now and then to notice a closed camera


class CameraInfo(BaseModel):
    name: str
    source: str
    description: str
    signal: bool
    reason: str | None
    width: int
    height: int
    configured_fps: float
    delivered_fps: float
    frames: int
    frames_dropped: int
    encodes: int
    encode_ms: float
    passthrough_frames: int
    clients: int
    last_frame_time: float | None
    last_frame_age_s: float | None
    opens: int


class CamerasReply(BaseModel):
    server_time: float  # Unix seconds when this reply was made (browser clock check)
    cameras: list[CameraInfo]


def frame_time_header(frame: Frame) -> str:
    return f"{frame.t_wall:.6f}"


class _PartCache:
    """The multipart part of a camera's newest frame, built once for every viewer."""

    __slots__ = ("version", "part")

    def __init__(self) -> None:
        self.version = 0
        self.part = b""

    def get(self, item: Versioned[Frame]) -> bytes:
        if item.version != self.version:
            frame = item.value
            head = (
                f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n"
                f"Content-Length: {len(frame.jpeg)}\r\n"
                f"X-Frame-Seq: {frame.seq}\r\nX-Frame-Time: {frame_time_header(frame)}\r\n"
                f"X-Frame-Signal: {int(frame.signal)}\r\n\r\n"
            ).encode("ascii")
            self.part, self.version = head + frame.jpeg + b"\r\n", item.version
        return self.part


_parts: weakref.WeakKeyDictionary[object, _PartCache] = weakref.WeakKeyDictionary()


def _camera(request: Request, name: str):
    cameras = request.app.state.station.cameras
    camera = cameras.get(name)
    if camera is None:
        known = ", ".join(sorted(cameras)) or "none"
        raise NotFound(f"No camera '{name}'; cameras: {known}.")
    return camera


async def _mjpeg(camera, cache: _PartCache) -> AsyncIterator[bytes]:
    frames = camera.frames
    with camera.watching():  # leaves on disconnect too: the generator is closed or cancelled
        version = 0
        while not frames.closed:
            item = await frames.wait_newer(version, timeout=_IDLE_WAIT_S)
            if item is None or item.version <= version:
                continue
            version = item.version
            yield cache.get(item)


@router.get(
    "/video/{camera}.mjpg",
    summary="Live MJPEG stream of one camera",
    response_class=StreamingResponse,
    responses={200: {"content": {f"multipart/x-mixed-replace; boundary={BOUNDARY}": {}}}},
)
async def get_stream(camera: str, request: Request) -> StreamingResponse:
    cam = _camera(request, camera)
    cache = _parts.setdefault(cam, _PartCache())
    return StreamingResponse(
        _mjpeg(cam, cache),
        media_type=f"multipart/x-mixed-replace; boundary={BOUNDARY}",
        headers={**_NO_CACHE, "X-Accel-Buffering": "no"},
    )


@router.get(
    "/video/{camera}.jpg",
    summary="The newest frame of one camera",
    response_class=Response,
    responses={200: {"content": {"image/jpeg": {}}}},
)
async def get_snapshot(camera: str, request: Request) -> Response:
    item = _camera(request, camera).frames.get()
    if item is None:
        raise Unavailable(f"Camera '{camera}' has no frame yet.")
    frame = item.value
    headers = {
        **_NO_CACHE,
        "X-Frame-Seq": str(frame.seq),
        "X-Frame-Time": frame_time_header(frame),
        "X-Frame-Signal": str(int(frame.signal)),
    }
    return Response(frame.jpeg, media_type="image/jpeg", headers=headers)


@router.get("/api/cameras", response_model=CamerasReply, summary="Every camera's figures")
async def get_cameras(request: Request) -> CamerasReply:
    cameras = request.app.state.station.cameras
    infos = [CameraInfo.model_validate(c.stats(), from_attributes=True) for c in cameras.values()]
    return CamerasReply(server_time=time.time(), cameras=infos)
