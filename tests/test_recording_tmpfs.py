"""A really full disk: the recorder on a tiny tmpfs (needs root to mount; skipped otherwise)."""

import asyncio
import contextlib
import json
import subprocess
import time

import pytest

from companion.recording import layout
from companion.recording.recorder import Recorder, RecorderOptions
from companion.recording.session import SessionConfig
from companion.recording.writer import WriterLimits
from tests.recording_fakes import FakeCamera, FakeVehicle, make_jpegs


@contextlib.contextmanager
def tmpfs(path, size_kb: int):
    path.mkdir()
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs", str(path)],
        capture_output=True,
        text=True,
    )
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def record_until_stopped(root, min_free_bytes: int, timeout_s: float = 20.0):
    cam = FakeCamera("front", 30.0, make_jpegs(4, 320, 240)).start()  # ~1.5 MB/s
    vehicle = FakeVehicle().start()
    options = RecorderOptions(
        session=SessionConfig(
            rate_hz=30.0, source="sim", limits=WriterLimits(min_free_bytes=min_free_bytes)
        ),
        auto_record_on_arm=False,
    )
    rec = Recorder(root, vehicle.state, {"front": cam.frames}, options)

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
        cam.stop()
        vehicle.stop()


@pytest.mark.parametrize(
    "min_free_kb,expect", [(5120, "MB free, under the"), (0, "No space left on device")]
)
def test_full_tmpfs_stops_cleanly_with_reason(tmp_path, min_free_kb, expect):
    """5 MB: the free-space threshold stops it; 0: writes fail with ENOSPC and stop it."""
    with tmpfs(tmp_path / "disk", 8192) as root:
        st = record_until_stopped(root, min_free_kb * 1024)
        assert not st.recording, "recording did not stop on a full disk"
        reason = st.last_stop.reason
        assert reason.startswith("disk full") and expect in reason, reason
        meta = json.loads((root / st.last_stop.id / layout.SESSION_JSON).read_text())
        assert meta["status"] == "complete" and meta["stop_reason"] == reason
        assert meta["quality"]["cameras"]["front"]["frames_written"] > 5
        with open(root / st.last_stop.id / layout.TELEMETRY_CSV) as f:
            assert f.readline().startswith("t_s,wall_time,")


def test_recording_resumes_by_itself_when_the_disk_has_room_again(tmp_path):
    """A write failure while flying is not the end of the flight's data: the recorder
    tries again (1 s, doubling) and starts a new session once the cause has passed."""
    import shutil

    with tmpfs(tmp_path / "disk", 8192) as root:
        cam = FakeCamera("front", 30.0, make_jpegs(4, 320, 240)).start()  # ~1.5 MB/s
        vehicle = FakeVehicle().start()
        vehicle.armed = True
        options = RecorderOptions(
            session=SessionConfig(
                rate_hz=30.0, source="sim", limits=WriterLimits(min_free_bytes=0)
            ),
            auto_record_on_arm=True,
        )
        rec = Recorder(root, vehicle.state, {"front": cam.frames}, options)

        async def run():
            await rec.open()
            try:
                deadline = time.monotonic() + 30
                while rec.failure is None and time.monotonic() < deadline:  # noqa: ASYNC110
                    await asyncio.sleep(0.1)
                assert rec.failure is not None and rec.failure.startswith("disk full"), rec.failure
                first = rec.last_stop.id
                cam.stop()  # fewer bytes per second, and room made: the cause has passed
                shutil.rmtree(root / first)
                deadline = time.monotonic() + 20
                while rec.recording_id in (None, first) and time.monotonic() < deadline:  # noqa: ASYNC110
                    await asyncio.sleep(0.1)
                status = rec.status()
                assert status.recording and status.id != first, status
                assert rec.failure is None
            finally:
                await rec.aclose()

        try:
            asyncio.run(run())
        finally:
            cam.stop()
            vehicle.stop()
