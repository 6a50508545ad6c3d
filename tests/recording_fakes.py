"""Inputs for recorder tests: the station's own objects, fed by threads.

Cameras publish real JPEGs (OpenCV) into `Latest[Frame]` at a paced rate from their own
thread, as a capture thread does; the vehicle state is published as fresh snapshots;
MAVLink packets are real pymavlink-encoded bytes. `FakeRig` wires them to a real Recorder
as the station does.
"""

from __future__ import annotations

import asyncio
import os
import threading
import time
from collections import namedtuple
from pathlib import Path

import cv2
import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from fpv_station.companion.latest import Latest
from fpv_station.companion.recording import frame_pack, layout
from fpv_station.companion.recording.recorder import Recorder, RecorderOptions
from fpv_station.companion.recording.session import SessionConfig
from fpv_station.companion.recording.writer import WriterLimits
from fpv_station.companion.vehicle_state import Heartbeat, PilotAltitude, RcChannels, VehicleState
from fpv_station.companion.video_frame import Frame


async def until(predicate, within_s: float) -> bool:
    """Poll `predicate` on the loop (the recorder's state has no event to wait on)."""
    for _ in range(int(within_s / 0.05)):
        if predicate():
            return True
        await asyncio.sleep(0.05)
    return bool(predicate())


def starve(hog: list[int]) -> None:
    """Take every free descriptor of this process into `hog` (until EMFILE). Call it again
    at each poll: one something closes would otherwise be free for its next open."""
    try:
        while True:
            hog.append(os.open(os.devnull, os.O_RDONLY))
    except OSError:
        pass


def make_jpegs(n: int = 8, width: int = 320, height: int = 240) -> list[bytes]:
    rng = np.random.default_rng(1)
    out = []
    for i in range(n):
        img = rng.integers(0, 255, (height, width, 3), dtype=np.uint8)
        cv2.putText(img, str(i), (20, 100), cv2.FONT_HERSHEY_SIMPLEX, 3, (255, 255, 255), 5)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 80])
        assert ok
        out.append(buf.tobytes())
    return out


def recorded_frames(folder: Path, camera: str) -> dict[str, bytes]:
    """Every frame frames.csv lists whose bytes are on disk, by name (`front/00000042.jpg`),
    read the way the station reads them (either session format)."""
    index = frame_pack.read_index(folder, camera)
    if index is None:
        return {}
    out = {}
    for k in range(len(index)):
        try:
            out[index.name(k)] = frame_pack.frame_bytes(folder, index, k)
        except frame_pack.FrameNotOnDisk:
            pass
    return out


def as_format_1(folder: Path) -> None:
    """Turn a recorded session into format 1, as the recorder wrote it before the frame
    pack: a file per frame (`front/00000042.jpg`), frames.csv without `offset`, no
    frames.mjpeg, session.json `format_version` 1."""
    import csv
    import json

    for cam_dir in sorted(p for p in folder.iterdir() if (p / layout.FRAMES_CSV).is_file()):
        frames = recorded_frames(folder, cam_dir.name)
        with open(cam_dir / layout.FRAMES_CSV, newline="") as f:
            rows = list(csv.DictReader(f))
        for rel, data in frames.items():
            (folder / rel).write_bytes(data)
        with open(cam_dir / layout.FRAMES_CSV, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(layout.FRAME_COLUMNS_V1)
            w.writerows([r[c] for c in layout.FRAME_COLUMNS_V1] for r in rows)
        (cam_dir / layout.FRAMES_PACK).unlink()
    meta_path = folder / layout.SESSION_JSON
    meta = json.loads(meta_path.read_text())
    meta["format_version"] = layout.FORMAT_FILE_PER_FRAME
    meta_path.write_text(json.dumps(meta, indent=2))


class FakeCamera:
    """A capture thread: publishes frame `seq` every 1/fps s, stamped at capture time."""

    def __init__(self, name: str, fps: float, jpegs: list[bytes]) -> None:
        self.name = name
        self.fps = fps
        self.jpegs = jpegs
        self.frames: Latest[Frame] = Latest()
        self.published: dict[int, bytes] = {}
        self.published_mono: dict[int, float] = {}  # when publish() had returned
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"fake-cam-{name}", daemon=True)

    def start(self) -> FakeCamera:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)

    def _run(self) -> None:
        period = 1.0 / self.fps
        next_t = time.monotonic()
        seq = 0
        while not self._stop.is_set():
            now = time.monotonic()
            if now < next_t:
                self._stop.wait(next_t - now)
                continue
            seq += 1
            jpeg = self.jpegs[seq % len(self.jpegs)]
            self.published[seq] = jpeg
            self.frames.publish(
                Frame(self.name, seq, jpeg, 320, 240, time.monotonic(), time.time())
            )
            self.published_mono[seq] = time.monotonic()
            next_t += period


class FakeVehicle:
    """Publishes VehicleState snapshots at `rate_hz` and real MAVLink packets to listeners."""

    def __init__(self, rate_hz: float = 50.0) -> None:
        self.rate_hz = rate_hz
        self.state: Latest[VehicleState] = Latest(VehicleState())
        self.listeners: list = []
        self.packets_sent = 0
        self.armed = False
        self._armed_since: float | None = None
        self.alt_m = 0.0
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fake-vehicle", daemon=True)

    def start(self) -> FakeVehicle:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)

    def publish_now(self) -> None:
        now = time.monotonic()
        # The flight timer as the state tracker keeps it: from the first state armed.
        if self.armed and self._armed_since is None:
            self._armed_since = now
        elif not self.armed:
            self._armed_since = None
        self.state.publish(
            VehicleState(
                heartbeat=Heartbeat(
                    t_mono=now,
                    sysid=1,
                    compid=1,
                    autopilot="px4",
                    armed=self.armed,
                    mode="POSCTL",
                    armed_since_mono=self._armed_since,
                ),
                rc=RcChannels(t_mono=now, chancount=8, pwm_us=(1500, 1500, 1100, 1500) + (0,) * 14),
                altitude=PilotAltitude(
                    t_mono=now,
                    relative_alt_m=self.alt_m,
                    reference_alt_m=180.0,
                    reference="arming" if self.armed else "first_fix",
                    home_lat_deg=43.0021,
                    home_lon_deg=-78.7875,
                ),
            )
        )

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        k = 0
        while not self._stop.wait(period):
            self.publish_now()
            k += 1
            msgs = [self.mav.attitude_encode(k * 20, 0.01, -0.02, 1.5, 0.0, 0.0, 0.0)]
            if k % int(self.rate_hz) == 0:
                msgs.append(self.mav.heartbeat_encode(2, 12, 128 if self.armed else 0, 0, 4, 3))
            for msg in msgs:
                packet = msg.pack(self.mav)
                self.packets_sent += 1
                for cb in self.listeners:
                    cb(time.time(), packet)


def recorder_options(
    min_free_bytes: int = 1, auto_record_on_arm: bool = False, **options
) -> RecorderOptions:
    """Sessions at 30 Hz from a "sim" source, with a free-space floor of `min_free_bytes`."""
    session = SessionConfig(
        rate_hz=30.0, source="sim", limits=WriterLimits(min_free_bytes=min_free_bytes)
    )
    return RecorderOptions(session=session, auto_record_on_arm=auto_record_on_arm, **options)


class FakeRig:
    """Fake cameras (30 fps) and vehicle feeding a real Recorder, its packet listener
    hooked to the vehicle as the station hooks it to the link."""

    def __init__(
        self,
        root,
        options: RecorderOptions,
        cameras: tuple[str, ...] = ("front",),
        jpegs: list[bytes] | None = None,
    ) -> None:
        jpegs = jpegs or make_jpegs()
        self.cameras = {n: FakeCamera(n, 30.0, jpegs) for n in cameras}
        self.vehicle = FakeVehicle()
        slots = {n: c.frames for n, c in self.cameras.items()}
        self.recorder = Recorder(root, self.vehicle.state, slots, options)
        self.vehicle.listeners.append(self.recorder.on_packet)

    def start(self) -> FakeRig:
        for cam in self.cameras.values():
            cam.start()
        self.vehicle.start()
        return self

    def stop(self) -> None:
        for cam in self.cameras.values():
            cam.stop()
        self.vehicle.stop()


DiskUsage = namedtuple("DiskUsage", "total used free")  # shutil.disk_usage's answer, to fake


def big_jpegs() -> list[bytes]:
    """Frames large enough to fill a small disk quickly."""
    return make_jpegs(4, 320, 240)  # ~1.5 MB/s at 30 fps: a tiny disk fills in seconds


def record_until_stopped(root, min_free_bytes: int, timeout_s: float = 20.0):
    """Record big frames under `root` until the recorder stops itself (a full disk, say)
    or `timeout_s` passes; the recorder's status then."""
    rig = FakeRig(root, recorder_options(min_free_bytes), jpegs=big_jpegs()).start()
    rec = rig.recorder

    async def run():
        await rec.open()
        await rec.start("test")
        deadline = time.monotonic() + timeout_s
        while rec.recording_id is not None and time.monotonic() < deadline:  # noqa: ASYNC110
            await asyncio.sleep(0.1)
        return rec.status()

    try:
        return asyncio.run(run())
    finally:
        rig.stop()
