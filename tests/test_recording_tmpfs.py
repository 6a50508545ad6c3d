"""A really full disk: the recorder on a tiny tmpfs (needs root to mount; skipped otherwise),
and a write past RLIMIT_FSIZE (EFBIG, any user), which fails the way ENOSPC does."""

import asyncio
import contextlib
import json
import subprocess
import time

import pytest
from pymavlink import mavutil

from fpv_station.companion.recording import layout
from tests.processes import complete_rows, read_line, spawn
from tests.recording_fakes import (
    FakeRig,
    big_jpegs,
    record_until_stopped,
    recorder_options,
)


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


@pytest.mark.parametrize(
    "min_free_kb,expect", [(5120, "MB free, under the"), (0, "No space left on device")]
)
def test_full_tmpfs_stops_cleanly_with_reason(tmp_path, min_free_kb, expect):
    """5 MB: the free-space threshold stops it; 0: writes fail with ENOSPC and stop it.
    Either way the session is marked cut short."""
    with tmpfs(tmp_path / "disk", 8192) as root:
        st = record_until_stopped(root, min_free_kb * 1024)
        assert not st.recording, "recording did not stop on a full disk"
        reason = st.last_stop.reason
        assert reason.startswith("disk full") and expect in reason, reason
        meta = assert_report_is_what_is_on_disk(root / st.last_stop.id)
        assert meta["stop_reason"] == reason


def test_a_write_past_the_file_size_limit_cuts_the_session_short(tmp_path):
    """No root needed: a process under RLIMIT_FSIZE gets EFBIG from the write that would
    cross it, cut where the limit falls, as ENOSPC cuts writes on a full disk."""
    proc = spawn(["-m", "tests.record_under_file_limit", str(tmp_path), str(2 << 20)])
    try:
        sid = read_line(proc, "STOPPED ", timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    meta = assert_report_is_what_is_on_disk(tmp_path / sid)
    assert meta["stop_reason"].startswith("write error") and "too large" in meta["stop_reason"]


def assert_report_is_what_is_on_disk(folder) -> dict:
    """A session cut short by a failed write: its report states what is on disk, not
    what the writer had handed to buffers that the failed flush lost."""
    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    assert meta["status"] == "cut_short"
    with open(folder / layout.TELEMETRY_CSV) as f:
        assert f.readline().startswith("t_s,wall_time,")
    q = meta["quality"]
    assert q["telemetry_rows"] == len(complete_rows(folder / layout.TELEMETRY_CSV)) > 0
    mlog = mavutil.mavlink_connection(str(folder / layout.MAVLINK_TLOG))
    packets = 0
    while mlog.recv_msg() is not None:
        packets += 1
    assert q["tlog_packets"] == packets
    # frames.csv lists whole JPEGs back to back from the pack's start, and the pack ends
    # with the last of them: the frame (or batch) the failed write cut is gone.
    listed = complete_rows(folder / layout.frames_csv_relpath("front"))
    pack = (folder / layout.frames_pack_relpath("front")).read_bytes()
    ends = [int(r["offset"]) + int(r["bytes"]) for r in listed]
    assert [int(r["offset"]) for r in listed] == [0, *ends[:-1]] and len(pack) == ends[-1]
    frames = [pack[int(r["offset"]) : end] for r, end in zip(listed, ends, strict=True)]
    assert all(j.startswith(b"\xff\xd8") and j.endswith(b"\xff\xd9") for j in frames)
    assert not list(folder.glob("front/*.jpg"))
    front = q["cameras"]["front"]
    assert front["frames_written"] == len(listed) > 5
    assert front["frames_captured"] == front["frames_written"] + front["frames_dropped"]
    return meta


def test_recording_resumes_by_itself_when_the_disk_has_room_again(tmp_path, caplog):
    """A write failure while flying is not the end of the flight's data: the recorder
    tries again (1 s, doubling) and starts a new session once the cause has passed, and
    its log says after what."""
    import logging
    import shutil

    caplog.set_level(logging.INFO, logger="fpv_station.companion.recording.recorder")

    with tmpfs(tmp_path / "disk", 8192) as root:
        rig = FakeRig(root, recorder_options(0, auto_record_on_arm=True), jpegs=big_jpegs())
        rig.vehicle.armed = True
        rec, cam = rig.start().recorder, rig.cameras["front"]

        async def run():
            await rec.open()
            try:
                deadline = time.monotonic() + 30
                while rec.failure is None and time.monotonic() < deadline:  # noqa: ASYNC110
                    await asyncio.sleep(0.1)
                assert rec.failure is not None and rec.failure.startswith("disk full"), rec.failure
                first = rec.last_stop.id
                cam.stop()  # fewer bytes per second, and room made: the cause has passed

                def finalized() -> bool:  # the stop counts the files; let it finish first
                    try:
                        meta = json.loads((root / first / layout.SESSION_JSON).read_text())
                    except (OSError, ValueError):
                        return False
                    return meta["status"] != layout.STATUS_RECORDING

                deadline = time.monotonic() + 20
                while not finalized() and time.monotonic() < deadline:  # noqa: ASYNC110
                    await asyncio.sleep(0.1)
                shutil.rmtree(root / first)
                deadline = time.monotonic() + 20
                while rec.recording_id in (None, first) and time.monotonic() < deadline:  # noqa: ASYNC110
                    await asyncio.sleep(0.1)
                status = rec.status()
                assert status.recording and status.id != first, status
                assert rec.failure is None
                assert "recording resumed after: disk full" in caplog.text, caplog.text
            finally:
                await rec.aclose()

        try:
            asyncio.run(run())
        finally:
            rig.stop()


def test_a_cut_session_whose_files_cannot_be_counted_is_still_finished(tmp_path, monkeypatch):
    """At a failed write's stop the files are counted; when they cannot be read (EIO, or
    here a file where the camera folder was), the stop once raised and left session.json
    saying "recording". It ends cut short, with the reason and the writer's counts, and
    says it was not recounted (no `recovery`). The stop: the disk is full (its free
    space, as the OS reports it)."""
    import shutil

    real = shutil.disk_usage
    full = {"now": False}
    monkeypatch.setattr(
        shutil,
        "disk_usage",
        lambda p: real(p)._replace(free=0) if full["now"] else real(p),
    )
    rig = FakeRig(tmp_path, recorder_options(1), jpegs=big_jpegs()).start()
    rec = rig.recorder

    async def run() -> str:
        await rec.open()
        sid = (await rec.start("test")).id
        deadline = time.monotonic() + 30
        while rec.status().frames_written.get("front", 0) < 3 and time.monotonic() < deadline:  # noqa: ASYNC110
            await asyncio.sleep(0.05)
        front = tmp_path / sid / "front"
        front.rename(front.with_name("front.moved"))
        front.write_text("not a folder")  # before the loop runs the failed write's stop
        full["now"] = True
        deadline = time.monotonic() + 30
        while rec.recording_id is not None and time.monotonic() < deadline:  # noqa: ASYNC110
            await asyncio.sleep(0.05)
        await rec.aclose()
        return sid

    try:
        sid = asyncio.run(run())
    finally:
        rig.stop()
    meta = json.loads((tmp_path / sid / layout.SESSION_JSON).read_text())
    assert meta["status"] == "cut_short", meta["status"]
    assert meta["stop_reason"].startswith("disk full"), meta["stop_reason"]
    assert meta["recovery"] is None
    assert meta["quality"]["telemetry_rows"] > 0
    assert rec.last_stop is not None and rec.last_stop.reason == meta["stop_reason"]
