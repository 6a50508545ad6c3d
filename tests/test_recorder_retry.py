"""The recorder keeps recording through a real EMFILE: a process under a
lowered RLIMIT_NOFILE loses its descriptors mid-flight, the session is cut short with the
reason, the recorder reports the problem, and once descriptors are back it records again
into a new session, which ends when the vehicle disarms like the one arming started."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import gc
import json
import os
import shutil

import pytest

from fpv_station.companion.latest import Latest
from fpv_station.companion.recording.session import RecordingSession, SessionConfig
from fpv_station.companion.recording.writer import WriterLimits
from fpv_station.companion.vehicle_state import VehicleState
from fpv_station.companion.video_frame import Frame
from tests.processes import read_line, spawn
from tests.recording_fakes import DiskUsage, FakeRig, recorder_options, starve, until


def test_recording_goes_on_while_descriptors_run_out(tmp_path):
    """No descriptor left mid-flight (a real EMFILE) once failed the next frame's file and
    cut the session; with a frame pack per camera the writer opens nothing after its start,
    so the session records on through it and ends when the vehicle disarms."""
    proc = spawn(["-m", "tests.record_through_emfile", str(tmp_path)])
    try:
        first = read_line(proc, "FIRST ", timeout=60)
        starved = dict(kv.split("=", 1) for kv in read_line(proc, "STARVED ", timeout=60).split())
        assert starved["failure"] == "None" and starved["session"] == first, starved
        assert int(starved["frames"]) >= 30
        assert read_line(proc, "STOPPED ", timeout=60) == "disarmed"
        read_line(proc, "DONE", timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert [p.name for p in tmp_path.iterdir()] == [first]
    meta = json.loads((tmp_path / first / "session.json").read_text())
    assert meta["status"] == "complete" and meta["stop_reason"] == "disarmed"
    assert meta["quality"]["cameras"]["front"]["frames_written"] >= int(starved["frames"])


@contextlib.contextmanager
def descriptors_left(n: int):
    """Every descriptor of this process taken but `n` (opening /dev/null until EMFILE).
    The garbage collector is run first and held off meanwhile: a socket or file that an
    earlier test in this process left unreferenced would otherwise be closed by a
    collection inside the block, one more descriptor free than `n`."""
    hog: list[int] = []
    gc.collect()
    gc.disable()
    try:
        starve(hog)
        for _ in range(min(n, len(hog))):
            os.close(hog.pop())
        yield
    finally:
        for fd in hog:
            os.close(fd)
        gc.enable()


def open_under(folder) -> list[str]:
    """Files under `folder` that this process holds open."""
    paths = []
    for fd in os.listdir("/proc/self/fd"):
        with contextlib.suppress(OSError):  # the listing's own descriptor is gone
            paths.append(os.readlink(f"/proc/self/fd/{fd}"))
    return [p for p in paths if p.startswith(str(folder))]


@pytest.mark.parametrize("free", [0, 2, 5])
def test_a_session_that_cannot_open_its_files_leaves_nothing_behind(tmp_path, free):
    """The recorder retries a start every few seconds while descriptors are short: each
    failed start once left an empty session folder (listed as an "unreadable" session)
    and, when some files had opened, those descriptors, which the next retry then lacked.
    `free` = 2: telemetry.csv and mavlink.tlog open, messages.csv does not; 5: the front
    camera's frames.csv and frames.mjpeg open too, the bottom camera's do not."""
    state: Latest[VehicleState] = Latest()
    cams: dict[str, Latest[Frame]] = {"front": Latest(), "bottom": Latest()}
    config = SessionConfig(source="sim", limits=WriterLimits(min_free_bytes=1))
    with descriptors_left(free), pytest.raises(OSError) as failed:
        RecordingSession(tmp_path, state, cams, config)
    assert failed.value.errno == errno.EMFILE, failed.value
    del failed  # its traceback holds the half-built session; the files must not need it
    assert open_under(tmp_path) == []
    assert list(tmp_path.iterdir()) == []
    # Nor a listener on the slots: one more at each retry, each state and frame a call.
    assert state._listeners == () and all(c._listeners == () for c in cams.values())


def test_a_cause_that_has_not_passed_is_retried_ever_more_slowly(tmp_path):
    """The retry waits 1 s, then doubling to 30 s, while its starts fail. A start that
    works but whose session fails again at once (a card that fails every write; here
    every frame crosses RLIMIT_FSIZE) once reset the wait to 1 s: a new session folder
    about every second for as long as the flight lasts. Such a session's failure keeps
    doubling the wait: in 12 s the arming's session and retries after 1, 2 and 4 s."""
    proc = spawn(["-m", "tests.record_under_file_limit", str(tmp_path), str(16 * 1024), "12"])
    try:
        sessions = int(read_line(proc, "SESSIONS ", timeout=120))
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    assert 2 <= sessions <= 4, sorted(p.name for p in tmp_path.iterdir())
    for folder in tmp_path.iterdir():  # each one failed at once, and says so
        meta = json.loads((folder / "session.json").read_text())
        assert meta["status"] == "cut_short" and "too large" in meta["stop_reason"], meta


def test_a_start_refused_on_arming_is_retried_while_armed(tmp_path):
    """A real station with no descriptor left when the vehicle arms: the arming's start is
    refused (EMFILE). While armed, health is degraded with the reason and /api/status says
    NOT RECORDING; the start is tried again, so once descriptors are back the flight is
    recorded, and its session says how much of the flight came before it. Without the
    retry the flight would go unrecorded to its end."""
    proc = spawn(["-m", "tests.record_through_refused_start", str(tmp_path)])
    try:
        refused = read_line(proc, "REFUSED ", timeout=120)
        health, not_recording, reasons = refused.split(" ", 2)
        assert health == "health=degraded" and not_recording == "not_recording=True", refused
        reasons = json.loads(reasons.removeprefix("reasons="))
        assert any("Too many open files" in r for r in reasons), reasons
        assert any("armed" in r and "without a recording" in r for r in reasons), reasons
        started = read_line(proc, "STARTED ", timeout=30)
        assert read_line(proc, "HEALTH ", timeout=30) == "ok"
        assert read_line(proc, "STOPPED ", timeout=30) == "disarmed"
        read_line(proc, "DONE", timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    sid, trigger, _after = started.split()
    assert trigger == "trigger=retry"
    # The refused starts left no folder behind: one session, the flight's.
    assert [p.name for p in tmp_path.iterdir()] == [sid]
    meta = json.loads((tmp_path / sid / "session.json").read_text())
    assert meta["status"] == "complete" and meta["stop_reason"] == "disarmed"
    missed = meta["missed"]
    # Armed for the whole refusal (the script holds the descriptors 3 s) before it began,
    # and no session recorded any of it.
    assert missed["armed_before_start_s"] >= 3.0, missed
    assert missed["unrecorded_s"] == missed["armed_before_start_s"]
    assert "Too many open files" in missed["reason"]
    assert meta["arming"] is not None  # the rows after the start still know the arming


def test_a_start_refused_for_low_disk_is_retried_while_armed(tmp_path, monkeypatch):
    """Under the free-space minimum when the vehicle arms: each start is refused (and
    leaves nothing behind) while the recorder says so and tries again; once space is
    freed the flight is recorded, and its session says what it missed and why."""
    real = shutil.disk_usage
    free = {"bytes": 10 * 10**6}
    monkeypatch.setattr(
        shutil, "disk_usage", lambda p: DiskUsage(real(p).total, real(p).used, free["bytes"])
    )
    rig = FakeRig(
        tmp_path, recorder_options(50 * 10**6, auto_record_on_arm=True, post_disarm_tail_s=0.2)
    )
    rec, vehicle = rig.start().recorder, rig.vehicle

    async def run():
        await rec.open()
        vehicle.armed = True
        assert await until(lambda: rec.last_error is not None, 10), "the start was not refused"
        await until(lambda: rec.status().not_recording, 10)
        refused, left = rec.status(), sorted(tmp_path.iterdir())
        free["bytes"] = 10**9  # space freed
        started = await until(lambda: rec.session is not None, 5.0)  # a hang guard
        trigger = rec.session.trigger if started else None
        await asyncio.sleep(0.5)
        vehicle.armed = False
        await until(lambda: rec.session is None, 10)
        await rec.aclose()
        return refused, left, started, trigger

    try:
        refused, left, started, trigger = asyncio.run(run())
    finally:
        rig.stop()
    assert not refused.recording and refused.not_recording, refused
    assert refused.last_error.startswith("disk full") and refused.armed_unrecorded_s >= 1.0
    assert left == []  # the refused starts made no folder
    assert started and trigger == "retry"
    (folder,) = tmp_path.iterdir()
    meta = json.loads((folder / "session.json").read_text())
    assert meta["status"] == "complete" and meta["stop_reason"] == "disarmed"
    missed = meta["missed"]
    assert missed["armed_before_start_s"] >= refused.armed_unrecorded_s
    assert missed["unrecorded_s"] == missed["armed_before_start_s"]
    assert missed["reason"].startswith("disk full")
