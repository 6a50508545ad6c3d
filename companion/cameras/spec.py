"""Camera specs: the URL-like strings that choose a camera's source.

    none                                   no camera (shows NO SIGNAL, costs nothing)
    v4l2:/dev/video0?width=640&height=480&fps=30&fourcc=MJPG
    v4l2:0                                 V4L2 device by index
    file:demo.mp4                          a video file, looped at the camera's fps
    folder:/path/to/images                 a folder of images (sorted by name), looped
    sim:front | sim:bottom                 the digital twin's rendered camera
    airsim:[HOST[:PORT]/]CAMERA?vehicle=Drone1&image_type=0&compress=0
                                           AirSim / Cosys-AirSim over msgpack-rpc

Options common to every source: width, height, fps, quality (override the camera's
settings). Parsing is pure and cheap so that settings validation can run it at start.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import parse_qsl

KINDS = ("none", "v4l2", "file", "folder", "sim", "airsim")
COMMON_OPTIONS = ("width", "height", "fps", "quality")
KIND_OPTIONS: dict[str, tuple[str, ...]] = {
    "none": (),
    "v4l2": ("fourcc",),
    "file": (),
    "folder": (),
    "sim": (),
    "airsim": ("vehicle", "image_type", "compress", "external"),
}
AIRSIM_DEFAULT_PORT = 41451
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".webp", ".tif", ".tiff")


class CameraSpecError(ValueError):
    """A camera spec that cannot be used; the message says what is wrong and what works."""


@dataclass(frozen=True, slots=True)
class CameraSpec:
    """A parsed camera spec. `target` is kind-specific (device, path, twin camera, ...)."""

    kind: str
    target: str = ""
    options: dict[str, str] = field(default_factory=dict)
    raw: str = "none"

    # Common overrides (None = use the camera's settings).
    @property
    def width(self) -> int | None:
        return _opt_int(self, "width", 16, 8192)

    @property
    def height(self) -> int | None:
        return _opt_int(self, "height", 16, 8192)

    @property
    def fps(self) -> float | None:
        value = self.options.get("fps")
        return None if value is None else _float(self, "fps", value, 0.1, 240.0)

    @property
    def quality(self) -> int | None:
        return _opt_int(self, "quality", 1, 100)

    # V4L2
    @property
    def device(self) -> str | int:
        return int(self.target) if self.target.isdigit() else self.target

    @property
    def fourcc(self) -> str | None:
        return self.options.get("fourcc")

    # AirSim
    @property
    def airsim_address(self) -> tuple[str, int, str]:
        """(host, port, camera name) of an airsim spec."""
        if "/" in self.target:
            hostport, camera = self.target.rsplit("/", 1)
        else:
            hostport, camera = "", self.target
        host, _, port = hostport.partition(":")
        port_num = int(port) if port else AIRSIM_DEFAULT_PORT
        return host or "127.0.0.1", port_num, camera


def parse_spec(raw: str, check_files: bool = True) -> CameraSpec:
    """Parse and validate a camera spec; raises CameraSpecError with a clear message."""
    text = raw.strip()
    if not text or text.lower() == "none":
        return CameraSpec("none", raw="none")
    if text.startswith("/dev/video"):  # a bare device path is unambiguous
        text = "v4l2:" + text
    kind, sep, rest = text.partition(":")
    kind = kind.lower()
    if not sep or kind not in KINDS:
        raise CameraSpecError(
            f"Camera spec '{raw}' has no known source kind; use one of "
            "none, v4l2:/dev/video0, v4l2:0, file:demo.mp4, folder:/path, sim:front, "
            "sim:bottom, airsim:HOST:PORT/CAMERA."
        )
    target, _, query = rest.partition("?")
    try:
        pairs = parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query))
    except ValueError:
        raise CameraSpecError(f"Camera spec '{raw}': cannot read options '{query}'.") from None
    options = dict(pairs)
    allowed = COMMON_OPTIONS + KIND_OPTIONS[kind]
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise CameraSpecError(
            f"Camera spec '{raw}': unknown option(s) {', '.join(unknown)}; "
            f"'{kind}' takes {', '.join(allowed)}."
        )
    spec = CameraSpec(kind, target, options, raw)
    _validate(spec, check_files)
    return spec


def _validate(spec: CameraSpec, check_files: bool) -> None:
    spec.width, spec.height, spec.fps, spec.quality  # noqa: B018 - each validates itself
    raw, target = spec.raw, spec.target
    if spec.kind == "v4l2":
        if not (target.isdigit() or target.startswith("/")):
            raise CameraSpecError(
                f"Camera spec '{raw}': give a device path (v4l2:/dev/video0) or index (v4l2:0)."
            )
        fourcc = spec.fourcc
        if fourcc is not None and len(fourcc) != 4:
            raise CameraSpecError(f"Camera spec '{raw}': fourcc must be 4 characters (MJPG, YUYV).")
    elif spec.kind in ("file", "folder"):
        if not target:
            raise CameraSpecError(f"Camera spec '{raw}': give a path, e.g. {spec.kind}:/path.")
        path = Path(target).expanduser()
        if check_files and spec.kind == "file" and not path.is_file():
            raise CameraSpecError(f"Camera spec '{raw}': video file '{path}' does not exist.")
        if check_files and spec.kind == "folder":
            if not path.is_dir():
                raise CameraSpecError(f"Camera spec '{raw}': folder '{path}' does not exist.")
            if not any(p.suffix.lower() in IMAGE_SUFFIXES for p in path.iterdir()):
                raise CameraSpecError(
                    f"Camera spec '{raw}': folder '{path}' holds no images "
                    f"({', '.join(IMAGE_SUFFIXES)})."
                )
    elif spec.kind == "sim":
        if not target:
            raise CameraSpecError(f"Camera spec '{raw}': name the twin camera, e.g. sim:front.")
    elif spec.kind == "airsim":
        hostport = target.rsplit("/", 1)[0] if "/" in target else ""
        port = hostport.partition(":")[2]
        if port and not (port.isdigit() and 0 < int(port) < 65536):
            raise CameraSpecError(f"Camera spec '{raw}': port '{port}' is not a TCP port.")
        if not spec.airsim_address[2]:
            raise CameraSpecError(
                f"Camera spec '{raw}': name the AirSim camera, e.g. airsim:127.0.0.1:41451/front_center."
            )
        for name in ("image_type",):
            if name in spec.options and not spec.options[name].isdigit():
                raise CameraSpecError(f"Camera spec '{raw}': {name} must be a number (0 = Scene).")
        for name in ("compress", "external"):
            if spec.options.get(name, "0") not in ("0", "1", "true", "false"):
                raise CameraSpecError(f"Camera spec '{raw}': {name} must be 0 or 1.")


def _opt_int(spec: CameraSpec, name: str, lo: int, hi: int) -> int | None:
    value = spec.options.get(name)
    if value is None:
        return None
    try:
        number = int(value)
    except ValueError:
        raise CameraSpecError(
            f"Camera spec '{spec.raw}': {name}='{value}' is not a whole number."
        ) from None
    if not lo <= number <= hi:
        raise CameraSpecError(f"Camera spec '{spec.raw}': {name}={number} is outside {lo}..{hi}.")
    return number


def _float(spec: CameraSpec, name: str, value: str, lo: float, hi: float) -> float:
    try:
        number = float(value)
    except ValueError:
        raise CameraSpecError(
            f"Camera spec '{spec.raw}': {name}='{value}' is not a number."
        ) from None
    if not lo <= number <= hi:
        raise CameraSpecError(
            f"Camera spec '{spec.raw}': {name}={number:g} is outside {lo:g}..{hi:g}."
        )
    return number


def flag(spec: CameraSpec, name: str, default: bool = False) -> bool:
    value = spec.options.get(name)
    return default if value is None else value in ("1", "true")
