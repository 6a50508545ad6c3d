"""List V4L2 video devices and their formats, for `fpv-station cameras`.

No v4l2-ctl needed: names come from /sys/class/video4linux, formats and frame sizes
from the V4L2 ioctls (VIDIOC_QUERYCAP, VIDIOC_ENUM_FMT, VIDIOC_ENUM_FRAMESIZES); when
those fail (permissions, odd drivers), OpenCV is asked what the device delivers.
"""

from __future__ import annotations

import fcntl
import os
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

SYSFS = Path("/sys/class/video4linux")


def _iowr(nr: int, size: int, read_only: bool = False) -> int:
    direction = 2 if read_only else 3  # _IOR = read, _IOWR = read|write
    return (direction << 30) | (size << 16) | (ord("V") << 8) | nr


_CAP = struct.Struct("16s32s32sIII12x")  # struct v4l2_capability (104 bytes)
_FMTDESC = struct.Struct("III32sII12x")  # struct v4l2_fmtdesc (64 bytes)
_FRMSIZE = struct.Struct("III6I8x")  # struct v4l2_frmsizeenum (44 bytes)
VIDIOC_QUERYCAP = _iowr(0, _CAP.size, read_only=True)
VIDIOC_ENUM_FMT = _iowr(2, _FMTDESC.size)
VIDIOC_ENUM_FRAMESIZES = _iowr(74, _FRMSIZE.size)
BUF_TYPE_VIDEO_CAPTURE = 1
CAP_VIDEO_CAPTURE = 0x1
CAP_DEVICE_CAPS = 0x80000000


@dataclass
class VideoFormat:
    fourcc: str
    description: str
    sizes: list[str] = field(default_factory=list)  # "640x480" or "16x16..1920x1080"


@dataclass
class VideoDevice:
    path: str
    name: str
    driver: str = ""
    capture: bool | None = None  # None = could not ask the driver
    formats: list[VideoFormat] = field(default_factory=list)
    note: str = ""


def list_devices(
    sysfs: Path = SYSFS, dev: Path = Path("/dev"), probe: bool = True
) -> list[VideoDevice]:
    if not sysfs.is_dir():
        return []
    devices = []
    for entry in sorted(sysfs.iterdir(), key=lambda p: _natural(p.name)):
        if not entry.name.startswith("video"):
            continue
        name = _read(entry / "name") or entry.name
        device = VideoDevice(path=str(dev / entry.name), name=name)
        if not os.path.exists(device.path):
            device.note = "listed by the kernel but missing in /dev"
        elif probe:
            _query(device)
        devices.append(device)
    return devices


def _query(device: VideoDevice) -> None:
    try:
        fd = os.open(device.path, os.O_RDWR | os.O_NONBLOCK)
    except OSError as exc:
        device.note = f"cannot open: {exc.strerror}"
        return
    try:
        buf = bytearray(_CAP.size)
        fcntl.ioctl(fd, VIDIOC_QUERYCAP, buf)
        driver, _card, _bus, _version, caps, device_caps = _CAP.unpack(buf)
        device.driver = driver.rstrip(b"\0").decode(errors="replace")
        effective = device_caps if caps & CAP_DEVICE_CAPS else caps
        device.capture = bool(effective & CAP_VIDEO_CAPTURE)
        if device.capture:
            device.formats = _formats(fd)
    except OSError as exc:
        device.note = (
            f"V4L2 query failed ({exc.strerror}); OpenCV says: {_opencv_probe(device.path)}"
        )
    finally:
        os.close(fd)


def _formats(fd: int) -> list[VideoFormat]:
    formats = []
    for index in range(64):
        buf = bytearray(_FMTDESC.pack(index, BUF_TYPE_VIDEO_CAPTURE, 0, b"", 0, 0))
        try:
            fcntl.ioctl(fd, VIDIOC_ENUM_FMT, buf)
        except OSError:
            break  # EINVAL: no more formats
        _i, _t, _flags, desc, pixfmt, _mbus = _FMTDESC.unpack(buf)
        fmt = VideoFormat(
            pixfmt.to_bytes(4, "little").decode(errors="replace"),
            desc.rstrip(b"\0").decode(errors="replace"),
        )
        for size_index in range(256):
            sbuf = bytearray(_FRMSIZE.pack(size_index, pixfmt, 0, 0, 0, 0, 0, 0, 0))
            try:
                fcntl.ioctl(fd, VIDIOC_ENUM_FRAMESIZES, sbuf)
            except OSError:
                break
            _si, _pf, kind, *v = _FRMSIZE.unpack(sbuf)
            if kind == 1:  # discrete
                fmt.sizes.append(f"{v[0]}x{v[1]}")
            else:  # continuous / stepwise: min_w, max_w, step_w, min_h, max_h, step_h
                fmt.sizes.append(f"{v[0]}x{v[3]}..{v[1]}x{v[4]}")
                break
        formats.append(fmt)
    return formats


def _opencv_probe(path: str) -> str:
    import cv2

    from fpv_station.companion.cameras.v4l2 import fourcc_text

    cap = cv2.VideoCapture(path, cv2.CAP_V4L2)
    try:
        if not cap.isOpened():
            return "cannot open it"
        return (
            f"{fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))} "
            f"{int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))}x{int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))} "
            f"@ {cap.get(cv2.CAP_PROP_FPS):g} fps"
        )
    finally:
        cap.release()


def format_devices(devices: list[VideoDevice]) -> str:
    if not devices:
        return (
            "No V4L2 video devices found (nothing in /sys/class/video4linux). "
            "Plug in a USB camera or grabber, or use file:, folder:, sim: or airsim: specs."
        )
    lines = []
    for d in devices:
        kind = {True: "capture", False: "not a capture device", None: ""}[d.capture]
        head = f"{d.path}  {d.name}" + (f"  [{d.driver}, {kind}]" if d.driver else "")
        lines.append(head)
        for fmt in d.formats:
            lines.append(f"    {fmt.fourcc}  {fmt.description}: {' '.join(fmt.sizes) or '?'}")
        if d.note:
            lines.append(f"    ({d.note})")
        if d.capture:
            lines.append(f"    use: --front v4l2:{d.path}?width=640&height=480&fps=30&fourcc=MJPG")
    return "\n".join(lines)


def _read(path: Path) -> str:
    try:
        return path.read_text().strip()
    except OSError:
        return ""


def _natural(name: str) -> list:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]
