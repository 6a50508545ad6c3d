"""Camera sources and the capture thread: rates, passthrough, NO SIGNAL, recovery."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest

from fpv_station.companion.cameras.jpeg import jpeg_size
from fpv_station.companion.cameras.rig import build_camera, effective_spec
from fpv_station.companion.cameras.settings import CameraConfig
from fpv_station.companion.cameras.spec import CameraSpecError, parse_spec
from fpv_station.companion.video_frame import Frame
from fpv_station.server.settings import SettingsError, load_settings
from tests.helpers import wait_until
from tests.video_fixtures import CountingRenderer, write_images


def _decode(jpeg: bytes) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert image is not None, "frame is not a decodable JPEG"
    return image


frame_versions: dict[int, int] = {}


# A paced source never runs faster than configured: the upper bound tells a paced source
# from a free-running one, which makes hundreds of small frames a second. A thread
# starved of CPU on a shared 2-core CI box skips late frames rather than bursting them
# (CI runs have shown 19 fps for 25), so the lower bound only says that frames flow; how
# close to the configured rate a camera keeps is benchmarks/video.py's figure.
def paced(rate: Rate, configured: float, seconds: float) -> bool:
    """What a source paced at `configured` makes over a `seconds` window: at most one slot
    more than the configured rate at each end of the window, and every slot accounted
    for, made or counted dropped (`CameraStats.frames_dropped`: late by whole frames on a
    loaded box). The account, not the frames made, has the lower bound: a starved box
    makes fewer frames, but its camera counts the slots it missed (up to one lost to
    rounding at each skip, so at least half)."""
    return rate.fps <= configured + 2 / seconds and rate.slots_per_s >= 0.5 * configured


@dataclass
class Rate:
    fps: float  # frames made in the window, per second
    slots_per_s: float  # frames made or counted dropped by the camera, per second
    frames: list[Frame] = field(repr=False)  # the signal frames seen


def _rate(camera, seconds: float) -> Rate:
    """Frames per second published by `camera` over `seconds` (signal frames only), and
    the camera's own account of its slots over the same time.

    Each frame seen gets the slot version it was published as (`frame_versions`): a
    polling reader on a loaded machine may miss a frame, the versions say whether the
    camera skipped a sequence number or the reader skipped a publish.
    """
    seen: list[Frame] = []
    first = camera.frames.get()
    start_version = first.version if first else 0
    before = camera.stats()
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        item = camera.frames.get()
        if item and item.version > start_version and (not seen or seen[-1].seq != item.value.seq):
            seen.append(item.value)
            frame_versions[id(item.value)] = item.version
        time.sleep(0.002)
    # The account is brought up to date by the camera's next frame (a starved capture
    # thread counts the slots it missed when it runs again).
    frames_by_now = camera.stats().frames
    assert wait_until(lambda: camera.stats().frames > frames_by_now, 60.0), "no frame came"
    after, elapsed = camera.stats(), time.monotonic() - t0
    slots = after.frames - before.frames + after.frames_dropped - before.frames_dropped
    good = [f for f in seen if f.signal]
    # Frames made in the window over its length: robust to the jitter of single frames.
    fps = (good[-1].seq - good[0].seq + 1) / seconds if good else 0.0
    return Rate(fps, slots / elapsed, good)


def test_specs_parse_and_bad_specs_are_clear(tmp_path):
    spec = parse_spec("v4l2:/dev/video0?width=640&height=480&fps=30&fourcc=MJPG")
    assert (spec.kind, spec.device, spec.width, spec.fps, spec.fourcc) == (
        "v4l2",
        "/dev/video0",
        640,
        30.0,
        "MJPG",
    )
    assert parse_spec("v4l2:1").device == 1
    assert parse_spec("airsim:10.0.0.5:41452/front_center").airsim_address == (
        "10.0.0.5",
        41452,
        "front_center",
    )
    assert parse_spec("airsim:bottom_center").airsim_address == (
        "127.0.0.1",
        41451,
        "bottom_center",
    )
    assert parse_spec("none").kind == "none"
    for bad, words in [
        ("webcam", "no known source kind"),
        ("v4l2:/dev/video0?fps=abc", "fps='abc' is not a number"),
        ("v4l2:/dev/video0?colour=1", "unknown option(s) colour"),
        ("v4l2:camera", "device path"),
        ("file:/no/such/file.mp4", "does not exist"),
        (f"folder:{tmp_path}", "holds no images"),
        ("airsim:host:99999/front", "not a TCP port"),
        ("sim:", "name the twin camera"),
        ("folder:/tmp?width=5", "outside 16..8192"),
    ]:
        with pytest.raises(CameraSpecError, match=words.replace("(", r"\(").replace(")", r"\)")):
            parse_spec(bad)
    # ... and at start, through the settings: one clear line naming the setting.
    with pytest.raises(SettingsError, match=r"cameras\.front\.spec.*webcam"):
        load_settings(environ={}, overrides={"cameras.front.spec": "webcam"})


def test_default_specs_follow_the_link_source():
    s = load_settings(environ={}, overrides={"link.source": "sim"})
    assert effective_spec("front", s.cameras.front.spec, s.link.source) == "sim:front"
    assert effective_spec("bottom", s.cameras.bottom.spec, "udpin:0.0.0.0:14550") == "none"
    s = load_settings(environ={"FPV_CAMERAS__BOTTOM__SPEC": "v4l2:2"}, overrides={})
    assert effective_spec("bottom", s.cameras.bottom.spec, "sim") == "v4l2:2"


def test_folder_source_loops_at_configured_rate_and_encodes_once(tmp_path):
    folder = write_images(tmp_path / "png", 4, (320, 240))  # PNG at the wrong size: scaled
    camera = build_camera(
        "front", CameraConfig(spec=f"folder:{folder}", fps=20, width=160, height=120)
    )
    camera.start()
    try:
        rate = _rate(camera, 1.5)
    finally:
        camera.stop()
    assert paced(rate, 20, 1.5), rate
    frames = rate.frames
    # One sequence number per published frame: seq steps equal publish (version) steps.
    seq_steps = [b.seq - a.seq for a, b in zip(frames, frames[1:])]
    version_steps = [
        frame_versions[id(b)] - frame_versions[id(a)] for a, b in zip(frames, frames[1:])
    ]
    assert seq_steps == version_steps and all(step >= 1 for step in seq_steps)
    assert _decode(frames[-1].jpeg).shape == (120, 160, 3)
    assert frames[-1].t_wall == pytest.approx(time.time(), abs=2.0)
    stats = camera.stats()
    assert stats.encodes == stats.frames and stats.passthrough_frames == 0
    assert stats.description.startswith("image folder")


def test_folder_of_jpegs_at_camera_size_is_passed_through(tmp_path):
    folder = write_images(tmp_path / "jpg", 3, (160, 120), suffix=".jpg")
    originals = {p.read_bytes() for p in folder.iterdir()}
    camera = build_camera(
        "bottom", CameraConfig(spec=f"folder:{folder}", fps=30, width=160, height=120)
    )
    camera.start()
    try:
        assert wait_until(lambda: camera.stats().frames >= 5, 10.0)
        frame = camera.frames.get().value
    finally:
        camera.stop()
    assert frame.jpeg in originals  # the very bytes of the file: no decode, no re-encode
    assert camera.stats().encodes == 0 and jpeg_size(frame.jpeg) == (160, 120)


def test_video_file_source_loops(tmp_path):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), 30, (160, 120))
    assert writer.isOpened()
    for i in range(5):
        writer.write(np.full((120, 160, 3), i * 40, np.uint8))
    writer.release()
    camera = build_camera("front", CameraConfig(spec=f"file:{path}", fps=25, width=160, height=120))
    camera.start()
    try:
        rate = _rate(camera, 1.2)
    finally:
        camera.stop()
    # More frames than the file holds, so it looped; paced at the 25 configured.
    assert rate.frames[-1].seq > 10 and paced(rate, 25, 1.2), rate
    assert camera.stats().opens == 1 and camera.stats().signal


def test_sim_source_at_configured_rate_and_recovers_from_a_failing_twin():
    renderer = CountingRenderer(320, 240)
    camera = build_camera(
        "bottom",
        CameraConfig(fps=30),
        link_source="sim",
        renderer=lambda: renderer,
        retry_min_s=0.1,
        retry_max_s=0.2,
    )
    camera.start()
    try:
        rate = _rate(camera, 1.5)
        assert paced(rate, 30, 1.5), rate
        frames = rate.frames
        assert renderer.calls["bottom"] >= len(frames) and "front" not in renderer.calls
        assert _decode(frames[-1].jpeg).shape == (480, 640, 3)  # scaled to the configured size
        renderer.fail.set()

        # A starved capture thread may first be reported stalled (no frame for 2 s); the
        # renderer's failure is what it says once it runs (hang guards, generous).
        def down() -> bool:
            reason = camera.stats().reason or ""
            return "renderer is down" in reason and "retry" in reason

        assert wait_until(down, 60.0), camera.stats().reason
        assert wait_until(lambda: not camera.frames.get().value.signal, 60.0)
        renderer.fail.clear()
        assert wait_until(lambda: camera.frames.get().value.signal, 60.0)  # by itself
    finally:
        camera.stop()
    assert camera.stats().opens >= 2


def test_sim_without_twin_shows_no_signal():
    camera = build_camera("front", CameraConfig(), link_source="sim", retry_min_s=0.1)
    camera.start()
    try:
        assert wait_until(lambda: camera.frames.get() is not None, 10.0)
        frame = camera.frames.get().value
    finally:
        camera.stop()
    assert not frame.signal and frame.camera == "front"
    assert "twin is not running" in camera.stats().reason
    assert _decode(frame.jpeg).shape == (480, 640, 3)


def test_v4l2_device_that_does_not_exist_gives_no_signal_and_retries(tmp_path):
    camera = build_camera(
        "bottom",
        CameraConfig(spec="v4l2:/dev/video-nonexistent-42?fourcc=MJPG", width=320, height=240),
        retry_min_s=0.1,
        retry_max_s=0.2,
    )
    folder = write_images(tmp_path / "imgs", 3, (160, 120))
    other = build_camera("front", CameraConfig(spec=f"folder:{folder}", width=160, height=120))
    camera.start()
    other.start()
    try:
        assert wait_until(lambda: camera.frames.get() is not None, 10.0)
        first = camera.frames.get()
        # Retried: newer NO SIGNAL frames keep coming, each saying what is wrong.
        assert wait_until(lambda: camera.frames.version >= first.version + 3, 10.0)
        frame = camera.frames.get().value
        stats = camera.stats()
        assert wait_until(lambda: other.stats().frames >= 20, 10.0)
    finally:
        camera.stop()
        other.stop()
    assert not frame.signal and frame.camera == "bottom" and frame.seq > first.value.seq
    assert "/dev/video-nonexistent-42 does not exist" in stats.reason
    assert stats.opens == 0 and stats.delivered_fps == 0.0
    assert _decode(frame.jpeg).shape == (240, 320, 3)
    # The other camera went on as if nothing happened.
    assert other.stats().signal and other.stats().opens == 1


def test_a_stalled_source_shows_no_signal_then_recovers():
    class StallingRenderer(CountingRenderer):
        def __init__(self):
            super().__init__(160, 120)
            self.stall_s = 0.0

        def render(self, camera):
            if self.stall_s:
                time.sleep(self.stall_s)
                self.stall_s = 0.0
            return super().render(camera)

    renderer = StallingRenderer()
    camera = build_camera(
        "front",
        CameraConfig(fps=30, width=160, height=120),
        link_source="sim",
        renderer=lambda: renderer,
        stall_s=0.4,
    )
    camera.start()
    try:
        assert wait_until(lambda: camera.stats().frames >= 3, 10.0)
        renderer.stall_s = 1.2
        assert wait_until(lambda: not camera.frames.get().value.signal, 10.0)
        assert camera.stats().reason.startswith("stalled")
        assert wait_until(lambda: camera.frames.get().value.signal, 10.0)
    finally:
        camera.stop()


def _voluntary_switches(thread) -> int:
    """How often `thread` blocked (about once per wake-up): Linux's count for it."""
    status = Path(f"/proc/self/task/{thread.native_id}/status").read_text()
    return int(status.split("voluntary_ctxt_switches:")[1].split()[0])


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="Linux's /proc counts")
def test_the_watchdog_sleeps_while_frames_flow():
    """The stall watchdog wakes when the newest frame would be `stall_s` old, not on a
    tick: while frames flow it costs no wake-up (it woke four times a second before)."""
    camera = build_camera(
        "front",
        CameraConfig(fps=30, width=160, height=120),
        link_source="sim",
        renderer=lambda: CountingRenderer(160, 120),
        stall_s=5.0,
    )
    camera.start()
    try:
        watchdog = next(t for t in threading.enumerate() if t.name == "camera-front-watchdog")
        assert wait_until(lambda: camera.stats().frames >= 3, 10.0)
        before = _voluntary_switches(watchdog)
        time.sleep(1.5)
        assert camera.stats().signal
        assert _voluntary_switches(watchdog) - before <= 1
    finally:
        camera.stop()


def test_device_listing_reads_sysfs_and_says_when_there_are_none(tmp_path):
    from fpv_station.companion.cameras.devices import format_devices, list_devices

    assert "No V4L2 video devices found" in format_devices(list_devices(tmp_path / "absent"))
    sysfs = tmp_path / "video4linux"
    for name, label in (("video10", "Grabber B"), ("video2", "USB2.0 PC CAMERA")):
        (sysfs / name).mkdir(parents=True)
        (sysfs / name / "name").write_text(label + "\n")
    devices = list_devices(sysfs, dev=tmp_path / "dev")
    assert [d.path for d in devices] == [
        str(tmp_path / "dev/video2"),
        str(tmp_path / "dev/video10"),
    ]
    assert devices[0].name == "USB2.0 PC CAMERA" and "missing in /dev" in devices[0].note
    # A /dev node that is no V4L2 device (a plain file): the query fails with a clear note.
    (tmp_path / "dev").mkdir()
    (tmp_path / "dev/video2").write_bytes(b"")
    device = list_devices(sysfs, dev=tmp_path / "dev")[0]
    assert "V4L2 query failed" in device.note and "OpenCV says" in device.note


def test_cameras_command_runs_here():
    import subprocess
    import sys

    out = subprocess.run(
        [sys.executable, "-m", "fpv_station.server", "cameras"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode == 0, out.stderr
    assert "/dev/video" in out.stdout or "No V4L2 video devices found" in out.stdout


class FakeUvcCapture:
    """Stands in for cv2.VideoCapture on a USB device (none exists here): what OpenCV's
    V4L2 backend returns with CAP_PROP_CONVERT_RGB off is the driver's raw buffer."""

    def __init__(self, fourcc: str, frames: list):
        self.props = {cv2.CAP_PROP_FOURCC: float(cv2.VideoWriter.fourcc(*fourcc))}
        self.frames = list(frames)
        self.released = False

    def isOpened(self):
        return True

    def set(self, prop, value):
        if prop == cv2.CAP_PROP_FOURCC:
            return True  # the device keeps its own format (props[FOURCC])
        self.props[prop] = value
        return True

    def get(self, prop):
        return self.props.get(prop, 0.0)

    def read(self):
        time.sleep(1 / 30)  # a device delivers at its frame rate
        if not self.frames:
            return False, None  # unplugged: OpenCV's read fails
        return True, self.frames.pop(0)

    def release(self):
        self.released = True


def test_v4l2_mjpeg_is_passed_through_untouched_and_a_lost_device_reopens():
    from fpv_station.companion.cameras.capture import Camera
    from fpv_station.companion.cameras.source import SourceConfig
    from fpv_station.companion.cameras.v4l2 import V4l2Source

    jpegs = [
        cv2.imencode(".jpg", np.full((240, 320, 3), 40 * i, np.uint8))[1].tobytes()
        for i in range(3)
    ]
    raw = [np.frombuffer(j + b"\0" * 64, np.uint8).reshape(1, -1) for j in jpegs]  # driver padding
    truncated = np.frombuffer(jpegs[0][:500], np.uint8).reshape(1, -1)
    devices = []

    def factory(device, api):
        assert (device, api) == (0, cv2.CAP_V4L2)
        # The first device is pulled after 4 buffers; the second (re-plugged) one streams.
        cap = FakeUvcCapture(
            "MJPG", [raw[0], truncated, raw[1], raw[2]] if not devices else raw * 100
        )
        devices.append(cap)
        return cap

    config = SourceConfig("front", 640, 480, 30.0, 80, stall_s=1.0)
    source = V4l2Source(config, 0, "MJPG", capture_factory=factory)
    camera = Camera(parse_spec("v4l2:0"), config, source, retry_min_s=0.1)
    seen = []
    camera.start()
    try:
        assert wait_until(lambda: len(devices) >= 2 and camera.stats().frames >= 4, 10.0)
        seen = [camera.frames.get().value]
    finally:
        camera.stop()
    stats = camera.stats()
    assert devices[0].props[cv2.CAP_PROP_CONVERT_RGB] == 0 and devices[0].released
    assert stats.encodes == 0 and stats.passthrough_frames == stats.frames
    assert stats.frames_dropped >= 1  # the truncated buffer was skipped, not shown
    assert seen[0].jpeg in jpegs and (seen[0].width, seen[0].height) == (320, 240)
    assert "MJPEG passthrough" in stats.description


def test_v4l2_raw_format_device_is_encoded_once_per_frame():
    from fpv_station.companion.cameras.capture import Camera
    from fpv_station.companion.cameras.source import SourceConfig
    from fpv_station.companion.cameras.v4l2 import V4l2Source

    frames = [np.full((120, 160, 3), i, np.uint8) for i in range(5)]
    config = SourceConfig("bottom", 160, 120, 30.0, 80)
    source = V4l2Source(
        config, 1, None, capture_factory=lambda d, a: FakeUvcCapture("YUYV", frames)
    )
    camera = Camera(parse_spec("v4l2:1"), config, source, retry_min_s=5.0)
    camera.start()
    try:
        assert wait_until(lambda: camera.stats().frames == 5, 10.0)
        assert wait_until(lambda: not camera.stats().signal, 10.0)  # then the device is gone
    finally:
        camera.stop()
    stats = camera.stats()
    assert stats.encodes == 5 and stats.passthrough_frames == 0
    assert "delivered no frame" in stats.reason and "YUYV" in stats.description


def test_sim_cameras_render_the_real_twin():
    from fpv_station.twin.runner import twin_from_settings

    twin = twin_from_settings(load_settings(environ={}).twin, None)
    cams = [
        build_camera(name, CameraConfig(fps=10), link_source="sim", renderer=lambda: twin)
        for name in ("front", "bottom")
    ]
    for cam in cams:
        cam.start()
    try:
        assert wait_until(lambda: all(c.stats().frames >= 3 for c in cams), 10.0)
        front, bottom = (_decode(c.frames.get().value.jpeg) for c in cams)
    finally:
        for cam in cams:
            cam.stop()
    assert front.shape == bottom.shape == (480, 640, 3)
    assert all(c.stats().description == f"digital twin camera '{c.name}'" for c in cams)
    # On the start pad the front camera sees sky above the horizon, the bottom one the pad:
    # two different views, not one picture twice.
    assert np.abs(front.astype(int) - bottom.astype(int)).mean() > 20


def test_a_cameras_declared_optics_reach_its_figures(tmp_path):
    """The tilt and vertical field of view set for a camera are in its figures (GET
    /api/cameras, which the OSD draws its horizon with); a camera with none set says so."""
    folder = write_images(tmp_path / "png", 2, (160, 120))
    cfg = CameraConfig(spec=f"folder:{folder}", tilt_up_deg=25.0, vfov_deg=70.0)
    stats = build_camera("front", cfg).stats()
    assert (stats.tilt_up_deg, stats.vfov_deg) == (25.0, 70.0)
    stats = build_camera("front", CameraConfig(spec=f"folder:{folder}")).stats()
    assert (stats.tilt_up_deg, stats.vfov_deg) == (None, None)
