"""Video: MJPEG streams, the newest frame, and the cameras' figures.

    GET /video/{camera}.mjpg   multipart/x-mixed-replace, one part per frame
    GET /video/{camera}.jpg    the newest frame
    GET /api/cameras           per camera: source, resolution, fps, drops, encode time, clients,
                               tilt and vertical field of view

Every viewer is an async generator (no thread per viewer, no queue) fed by the camera's
fan-out (`server.video_fanout`): one waiter on the camera's `Latest[Frame]`, each frame's
multipart part built once. A viewer that cannot keep up sits in its socket write; when
that returns it takes the newest part, skipping the ones it missed, so it never delays
the camera or another viewer.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import AsyncIterator

from fastapi import APIRouter, Request
from fastapi.responses import Response, StreamingResponse
from pydantic import BaseModel

from fpv_station.server.errors import NotFound, Unavailable
from fpv_station.server.video_fanout import BOUNDARY, frame_time_header

router = APIRouter(tags=["video"])

_NO_CACHE = {"Cache-Control": "no-store, no-cache, must-revalidate", "Pragma": "no-cache"}


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
    tilt_up_deg: float | None  # optical axis above the vehicle's nose, degrees
    vfov_deg: float | None  # vertical field of view, degrees; None when unknown


class CamerasReply(BaseModel):
    server_time: float  # Unix seconds when this reply was made (browser clock check)
    cameras: list[CameraInfo]


def _camera(request: Request, name: str):
    cameras = request.app.state.station.cameras
    camera = cameras.get(name)
    if camera is None:
        known = ", ".join(sorted(cameras)) or "none"
        raise NotFound(f"No camera '{name}'; cameras: {known}.")
    return camera


@router.get(
    "/video/{camera}.mjpg",
    summary="Live MJPEG stream of one camera",
    response_class=StreamingResponse,
    responses={200: {"content": {f"multipart/x-mixed-replace; boundary={BOUNDARY}": {}}}},
)
async def get_stream(camera: str, request: Request) -> StreamingResponse:
    cam = _camera(request, camera)
    station = request.app.state.station
    fanout = station.video_fanouts[camera]
    cap = station.client_limits.video
    cap.check()  # 503 now when full, before the stream starts

    async def held() -> AsyncIterator[bytes]:
        # The place is held while the stream runs (a generator that never starts holds
        # nothing); one taken in between by another viewer ends this stream at once.
        with contextlib.suppress(Unavailable), cap.slot():
            async for part in fanout.stream(cam.watching(), request.is_disconnected):
                yield part

    return StreamingResponse(
        held(),
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
