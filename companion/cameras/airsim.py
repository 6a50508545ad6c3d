"""AirSim / Cosys-AirSim cameras over their msgpack-rpc API, for hardware-in-the-loop.

One `simGetImages` call per frame with one ImageRequest for the named camera (a map
`{camera_name, image_type, pixels_as_float, compress}`, as AirSim's MsgpackMixin sends
it). The reply is a list of ImageResponse maps; `image_data_uint8` holds PNG bytes when
`compress` is set, otherwise raw pixels (HxWx3 BGR; 4 channels on old builds).

AirSim >= 1.5 takes `(requests, vehicle_name, external)`, Cosys-AirSim and older builds
`(requests, vehicle_name)`; rpclib rejects a wrong argument count with an error, so
the source starts with three arguments and falls back to two once.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from fpv_station.companion.cameras.msgpack_rpc import MsgpackRpcClient, RpcConnectionError, RpcError
from fpv_station.companion.cameras.source import (
    Captured,
    FrameSource,
    SourceConfig,
    SourceError,
    as_bgr,
)

SCENE = 0


def image_request(camera: str, image_type: int = SCENE, compress: bool = False) -> dict[str, Any]:
    return {
        "camera_name": str(camera),
        "image_type": int(image_type),
        "pixels_as_float": False,
        "compress": bool(compress),
    }


def decode_response(response: Any, camera: str) -> np.ndarray:
    """The BGR image of one ImageResponse map; SourceError if it holds none."""
    if not isinstance(response, dict):
        raise SourceError(f"AirSim sent a {type(response).__name__} instead of an ImageResponse")
    data = response.get("image_data_uint8")
    if isinstance(data, str):
        data = data.encode("utf-8", "surrogateescape")
    elif isinstance(data, list):
        data = bytes(data)
    width, height = int(response.get("width") or 0), int(response.get("height") or 0)
    if not data or len(data) <= 1 or width <= 0 or height <= 0:
        message = response.get("message") or "no image (is the camera name right?)"
        raise SourceError(f"AirSim camera '{camera}': {message}")
    if response.get("compress"):
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise SourceError(f"AirSim camera '{camera}': compressed image does not decode")
        return image
    channels, rest = divmod(len(data), width * height)
    if rest or channels not in (1, 3, 4):
        raise SourceError(
            f"AirSim camera '{camera}': {len(data)} bytes do not fit {width}x{height} pixels"
        )
    pixels = np.frombuffer(data, np.uint8).reshape(height, width, channels)
    return as_bgr(pixels if channels > 1 else pixels[:, :, 0], f"AirSim camera '{camera}'")


class AirSimSource(FrameSource):
    paced = True

    def __init__(
        self,
        config: SourceConfig,
        host: str,
        port: int,
        camera: str,
        vehicle: str = "",
        image_type: int = SCENE,
        compress: bool = False,
        external: bool = False,
    ) -> None:
        super().__init__(config)
        self.host, self.port, self.camera, self.vehicle = host, port, camera, vehicle
        self.request = image_request(camera, image_type, compress)
        self.external = external
        self._client = MsgpackRpcClient(host, port, timeout_s=config.stall_s)
        self._with_external = True

    def describe(self) -> str:
        vehicle = f" of {self.vehicle}" if self.vehicle else ""
        return f"AirSim {self.host}:{self.port} camera '{self.camera}'{vehicle}"

    def open(self) -> None:
        try:
            self._client.connect()
        except RpcConnectionError as exc:
            raise SourceError(f"AirSim not reachable: {exc}") from None

    def read(self) -> Captured | None:
        try:
            responses = self._get_images()
        except RpcConnectionError as exc:
            raise SourceError(f"AirSim connection lost: {exc}") from None
        except RpcError as exc:
            raise SourceError(f"AirSim refused simGetImages: {exc.error}") from None
        if not isinstance(responses, list) or not responses:
            raise SourceError(f"AirSim camera '{self.camera}': empty reply to simGetImages")
        image = decode_response(responses[0], self.camera)
        return Captured(image=image, width=image.shape[1], height=image.shape[0])

    def _get_images(self) -> Any:
        if self._with_external:
            try:
                return self._client.call(
                    "simGetImages", [self.request], self.vehicle, self.external
                )
            except RpcError as exc:
                if "argument" not in str(exc.error).lower():
                    raise
                self._with_external = False  # a (requests, vehicle_name) server
        return self._client.call("simGetImages", [self.request], self.vehicle)

    def close(self) -> None:
        self._client.close()
