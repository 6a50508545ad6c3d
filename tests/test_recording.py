import asyncio
import csv
import json
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from fpv_station.companion.cameras.rig import build_camera
from fpv_station.companion.cameras.settings import CameraConfig
from fpv_station.companion.latest import Latest
from fpv_station.companion.recording import layout
from fpv_station.companion.recording.recorder import Recorder, RecorderOptions
from fpv_station.companion.recording.session import RecordingSession, SessionConfig
from fpv_station.companion.recording.writer import WriterLimits
from fpv_station.companion.vehicle_state import Heartbeat, VehicleState
from fpv_station.companion.video_frame import Frame
from tests.helpers import CountingSelector, wait_until
from tests.recording_fakes import (
    DiskUsage,
    FakeCamera,
    FakeVehicle,
    make_jpegs,
    recorded_frames,
)
from tests.video_fixtures import write_images

FPS = 30.0


def options(rate_hz=30.0, **kw) -> RecorderOptions:
    session = SessionConfig(
        rate_hz=rate_hz,
        source="sim",
        camera_fps={"front": FPS, "bottom": FPS},
        limits=kw.pop("limits", WriterLimits(min_free_bytes=1)),
    )
    return RecorderOptions(session=session, **kw)


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_records_rows_at_rate_with_every_frame_and_small_skew(tmp_path):
    jpegs = make_jpegs()
    cams = {n: FakeCamera(n, FPS, jpegs).start() for n in layout.CAMERAS}
    vehicle = FakeVehicle().start()
    rec = Recorder(
        tmp_path,
        vehicle.state,
        {n: c.frames for n, c in cams.items()},
        options(rate_hz=30.0, auto_record_on_arm=False),
    )
    vehicle.listeners.append(rec.on_packet)

    t0 = {}

    async def run():
        await rec.open()
        status = await rec.start("test")
        assert status.recording and status.id
        t0["mono"] = rec.session.t0_mono
        await asyncio.sleep(3.0)
        t0["stop_from"] = time.monotonic()
        stopped = await rec.stop("requested")
        t0["stop_by"] = time.monotonic()
        return stopped

    status = asyncio.run(run())
    vehicle.stop()
    for c in cams.values():
        c.stop()
    # A stopped session listens to nothing (each listener is a call per state or frame).
    assert vehicle.state._listeners == ()
    assert all(c.frames._listeners == () for c in cams.values())
    sid = status.last_stop.id
    folder = tmp_path / sid
    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    assert meta["status"] == "complete" and meta["stop_reason"] == "requested"

    rows = read_csv(folder / layout.TELEMETRY_CSV)
    with open(folder / layout.TELEMETRY_CSV) as f:
        assert tuple(next(csv.reader(f))) == layout.telemetry_columns()
    t = np.array([float(r["t_s"]) for r in rows])
    # 30 a second from the start to the stop (however late a loaded box ran the stop)
    elapsed = (t0["stop_from"] - t0["mono"], t0["stop_by"] - t0["mono"])
    assert 80 <= elapsed[0] * 30 <= len(rows) <= elapsed[1] * 30 + 1, (len(rows), elapsed)
    assert abs(np.median(np.diff(t)) - 1 / 30) < 0.002
    assert meta["quality"]["telemetry_rows"] == len(rows)
    assert rows[-1]["rc.pwm_us.2"] == "1100" and rows[-1]["heartbeat.mode"] == "POSCTL"
    assert rows[-1]["heartbeat.armed"] == "0"
    assert float(rows[-1]["heartbeat.t_mono"]) <= float(rows[-1]["t_s"])  # session clock

    assert meta["format_version"] == layout.FORMAT_VERSION == 2
    for cam in layout.CAMERAS:
        referenced = {r[f"{cam}.file"] for r in rows if r[f"{cam}.file"]}
        # How many frames the camera threads made depends on the CPU they got (15 in 3 s
        # beside two hogs); each one named is checked below.
        assert len(referenced) >= 2
        on_disk = recorded_frames(folder, cam)
        for rel in referenced:
            seq = int(Path(rel).stem)
            assert on_disk[rel] == cams[cam].published[seq]
        # One pack a camera, no file per frame: the frames back to back, as streamed.
        assert sorted(p.name for p in (folder / cam).iterdir()) == [
            layout.FRAMES_CSV,
            layout.FRAMES_PACK,
        ]
        # Each row names the newest frame published before the row's instant (the
        # freshest it could have), never a frame from its future.
        done = sorted((t - t0["mono"], seq) for seq, t in cams[cam].published_mono.items())
        for r in rows:
            t_row = float(r["t_s"])
            newest_before = max((seq for t, seq in done if t < t_row), default=None)
            if newest_before is not None:
                assert int(r[f"{cam}.seq"]) >= newest_before, (t_row, r[f"{cam}.seq"])
            assert float(r[f"{cam}.skew_s"]) >= 0
        frames = read_csv(folder / layout.frames_csv_relpath(cam))
        seqs = [int(row["seq"]) for row in frames]
        assert [row["file"] for row in frames] == [layout.frame_relpath(cam, s) for s in seqs]
        pack = (folder / layout.frames_pack_relpath(cam)).read_bytes()
        assert pack == b"".join(cams[cam].published[s] for s in seqs)
        assert [int(row["offset"]) for row in frames] == np.cumsum(
            [0] + [int(row["bytes"]) for row in frames[:-1]]
        ).tolist()
        q = meta["quality"]["cameras"][cam]
        # Every frame is written or counted (the slot's listener takes each one).
        assert q["frames_written"] == len(frames) == len(set(seqs))
        assert q["frames_written"] + q["frames_dropped"] == q["frames_captured"]
        assert q["frames_captured"] >= seqs[-1] - seqs[0] + 1
        assert q["frames_dropped"] <= 0.1 * len(frames)
        assert FPS / 2 <= q["achieved_fps"] < FPS + 1.5  # paced; starved CI boxes skip frames
        skews = np.array([float(r[f"{cam}.skew_s"]) for r in rows if r[f"{cam}.skew_s"]])
        # Under one frame period while the camera keeps its pace (the rows and the camera
        # run at the same rate here, so skews are phase-locked, not spread). A camera
        # thread starved of CPU on a loaded box leaves longer gaps, which bound the skew.
        t_cap = np.array([float(row["t_s"]) for row in frames])
        assert np.median(skews) < 1 / FPS
        assert skews.max() <= np.diff(t_cap).max() + 1 / FPS
        assert q["skew_max_s"] == pytest.approx(skews.max(), abs=1e-5)

    # The tlog holds every packet, readable by pymavlink.
    mlog = mavutil.mavlink_connection(str(folder / layout.MAVLINK_TLOG))
    n = 0
    while (m := mlog.recv_match()) is not None:
        assert m.get_type() in ("ATTITUDE", "HEARTBEAT")
        assert abs(m._timestamp - meta["start_wall"]) < 10
        n += 1
    assert n == meta["quality"]["tlog_packets"] > 100
    assert meta["quality"]["tlog_packets_dropped"] == 0


def test_under_cpu_hogs_each_row_names_the_newest_frame_captured_by_its_instant(tmp_path):
    """Two processes spinning on the machine's cores while both real capture threads
    (stamp, then encode, then publish) record: every row names the newest recorded frame
    captured at or before its instant, so no skew is negative, and none is skipped
    because it was still being encoded when the writer took the row."""
    images = write_images(tmp_path / "png", 4, (320, 240))  # PNGs: each frame is encoded
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    cams = {
        n: build_camera(n, CameraConfig(spec=f"folder:{images}", fps=FPS, width=320, height=240))
        for n in layout.CAMERAS
    }
    vehicle = FakeVehicle()
    rec = Recorder(
        tmp_path / "sessions",
        vehicle.state,
        {n: c.frames for n, c in cams.items()},
        options(rate_hz=30.0, auto_record_on_arm=False),
    )

    async def run():
        await rec.open()
        await rec.start("test")
        await asyncio.sleep(3.0)
        return await rec.stop("requested")

    try:
        vehicle.start()
        for c in cams.values():
            c.start()
        assert wait_until(lambda: all(c.frames.get() for c in cams.values()), 10.0)
        status = asyncio.run(run())
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
        vehicle.stop()
        for c in cams.values():
            c.stop()
    folder = tmp_path / "sessions" / status.last_stop.id
    rows = read_csv(folder / layout.TELEMETRY_CSV)
    assert len(rows) >= 60, len(rows)
    for cam in layout.CAMERAS:
        frames = read_csv(folder / layout.frames_csv_relpath(cam))
        captured = np.array([float(f["t_s"]) for f in frames])
        seqs = [int(f["seq"]) for f in frames]
        # As many frames as the starved camera threads made (18 once): each is checked.
        assert len(frames) >= 2 and np.all(np.diff(captured) > 0)
        named = 0
        for r in rows:
            t_row = float(r["t_s"])
            # The newest frame at or before the row (the files round times to the
            # microsecond: a frame within one of the row's instant may be either side).
            k = int(np.searchsorted(captured, t_row + 1e-6, side="right"))
            k_sure = int(np.searchsorted(captured, t_row - 1e-6, side="right"))
            want = {str(seqs[i - 1]) if i else "" for i in range(k_sure, k + 1)}
            assert r[f"{cam}.seq"] in want, (cam, t_row, r[f"{cam}.seq"], want)
            if r[f"{cam}.seq"]:
                assert float(r[f"{cam}.skew_s"]) >= 0, (cam, t_row, r[f"{cam}.skew_s"])
                named += 1
        assert named >= len(rows) - 3, (cam, named, len(rows))  # the start held a frame


def test_rows_sit_on_the_grid_with_the_state_newest_at_each_instant_and_no_sampler_thread(
    tmp_path,
):
    """A live session takes its rows in the writer's thread, at each batch, from what
    the slots published and when: each row at its exact grid instant (k / rate_hz), with
    the state newest at that instant (never one from its future, never an older one),
    and the session's one thread is the writer: no sampler thread wakes at every instant
    (30 wake-ups a second) and stamps each row with when it woke."""
    vehicle = FakeVehicle(rate_hz=97.0).start()  # out of step with the 30 Hz rows
    # Each state's stamp and when it was published, noted before the recorder notes it
    # (this listener is the slot's first; one thread publishes, one state at a time).
    published: list[tuple[float, float]] = []
    vehicle.state.add_listener(lambda s: published.append((s.heartbeat.t_mono, time.monotonic())))
    rec = Recorder(tmp_path, vehicle.state, {}, options(rate_hz=30.0, auto_record_on_arm=False))

    async def run():
        await rec.open()
        await rec.start("test")
        threads = [t.name for t in threading.enumerate() if t.name.startswith("recorder")]
        t0 = rec.session.t0_mono
        await asyncio.sleep(2.0)
        status = await rec.stop("requested")
        return status, threads, t0

    status, threads, t0 = asyncio.run(run())
    vehicle.stop()
    assert threads == ["recorder-writer"]
    rows = read_csv(tmp_path / status.last_stop.id / layout.TELEMETRY_CSV)
    t = np.array([float(r["t_s"]) for r in rows])
    assert len(rows) >= 55, len(rows)
    assert np.allclose(t, np.arange(len(t)) / 30.0, atol=2e-6), t[:5]
    stamps = np.array([p[0] for p in published]) - t0
    noted = np.array([p[1] for p in published]) - t0
    for r in rows[1:]:  # the first row's state is the one held at the start
        t_row = float(r["t_s"])
        before_row = stamps[noted <= t_row]
        if not r["heartbeat.t_mono"]:  # the empty state held at the start: none published
            assert len(before_row) <= 1, (t_row, before_row[:3])  # (or one across the instant)
            continue
        named = float(r["heartbeat.t_mono"])
        assert named <= t_row + 1e-6, (t_row, named)
        # The newest one published by the instant; or the one before it, when the newest
        # was published across the instant (noted here just before it, by the recorder
        # just after). No time bound: a loaded box can hold the thread anywhere.
        assert named == pytest.approx(before_row[-1], abs=2e-6) or named == pytest.approx(
            before_row[-2], abs=2e-6
        ), (t_row, named, before_row[-3:])


def test_a_writer_held_up_past_the_state_history_skips_rows_it_cannot_know(tmp_path):
    """States kept for the writer's next batch are bounded (`state_history`). When more
    come before it runs (a disk that stalls the writer), the instants whose state was
    let go of get no row and are counted late; no row carries a state from after its
    instant or one older than what held then."""
    state: Latest[VehicleState] = Latest(VehicleState())
    # The writer held up: its one batch comes at the stop.
    stalled = WriterLimits(min_free_bytes=1, flush_interval_s=60.0, batch_interval_s=60.0)
    config = SessionConfig(rate_hz=100.0, state_history=8, limits=stalled)
    session = RecordingSession(tmp_path, state, {}, config)
    published: list[float] = []
    session.start()
    for _ in range(30):  # 30 states; the history keeps the last 8
        now = time.monotonic()
        state.publish(VehicleState(heartbeat=Heartbeat(t_mono=now)))
        published.append(now)
        time.sleep(0.005)
    time.sleep(0.1)
    meta = asyncio.run(session.stop("requested"))
    rows = read_csv(session.folder / layout.TELEMETRY_CSV)
    t = np.array([float(r["t_s"]) for r in rows])
    kept_from = published[-8] - session.t0_mono  # the oldest state still kept
    late = meta.quality.telemetry_ticks_late
    # The instants before it are skipped and counted; the rows start at the first one
    # after it, and the grid is whole.
    assert late >= 10 and t[0] == pytest.approx(late / 100, abs=2e-6), (late, t[0])
    assert kept_from - 1e-6 <= t[0] < kept_from + 0.05, (t[0], kept_from)  # 0.01 + a held thread
    assert np.allclose(np.diff(t), 0.01, atol=2e-6)
    times = np.array(published) - session.t0_mono
    for r in rows:
        t_row, named = float(r["t_s"]), float(r["heartbeat.t_mono"] or "nan")
        if t_row > times[-1] + 0.001:
            assert named == pytest.approx(times[-1], abs=2e-6)  # the last one holds
        elif named == named:  # nan: the state at the start (no heartbeat yet)
            assert named <= t_row + 1e-6


def test_a_burst_loses_no_frame_and_a_sequence_gap_is_counted(tmp_path):
    """Frames published faster than the event loop runs (ten with no await between them)
    are all written: the recorder takes them in the publisher's thread, not from the
    newest-wins slot. Frames the camera itself skipped (a gap in its sequence numbers)
    are counted as missed, never silent."""
    vehicle = FakeVehicle()
    cam = FakeCamera("front", FPS, make_jpegs(2))
    rec = Recorder(
        tmp_path, vehicle.state, {"front": cam.frames}, options(auto_record_on_arm=False)
    )
    skipped = {25, 26, 27}  # the camera never published these

    async def run():
        await rec.open()
        await rec.start("test")
        jpeg = cam.jpegs[0]
        seq = 0
        for _burst in range(5):
            for _ in range(10):
                seq += 1
                if seq not in skipped:
                    cam.frames.publish(
                        Frame("front", seq, jpeg, 320, 240, time.monotonic(), time.time())
                    )
            await asyncio.sleep(0.1)
        return seq, await rec.stop()

    published, status = asyncio.run(run())
    folder = tmp_path / status.last_stop.id
    q = json.loads((folder / layout.SESSION_JSON).read_text())["quality"]["cameras"]["front"]
    frames = read_csv(folder / layout.frames_csv_relpath("front"))
    assert [int(f["seq"]) for f in frames] == [s for s in range(1, 51) if s not in skipped]
    assert q["frames_written"] == len(frames) == published - len(skipped)
    assert q["frames_dropped"] == q["frames_missed"] == len(skipped)
    assert q["frames_captured"] == published
    rows = read_csv(folder / layout.TELEMETRY_CSV)
    assert_rows_name_frames_on_disk(folder, rows)


def test_auto_record_on_arm_with_post_disarm_tail(tmp_path):
    vehicle = FakeVehicle(rate_hz=20).start()
    rec = Recorder(tmp_path, vehicle.state, {}, options(post_disarm_tail_s=0.5))

    async def run():
        await rec.open()
        await asyncio.sleep(0.3)
        assert not rec.status().recording
        vehicle.armed = True
        vehicle.alt_m = 1.0
        for _ in range(200):
            await asyncio.sleep(0.05)
            if rec.status().recording:
                break
        st = rec.status()
        assert st.recording and st.trigger == "arm"
        await asyncio.sleep(0.5)
        vehicle.armed = False
        await asyncio.sleep(0.3)
        assert rec.status().recording and rec.status().stopping_at_wall is not None  # tail
        for _ in range(200):
            await asyncio.sleep(0.05)
            if rec.recording_id is None:  # stopped and finalized
                break
        st = rec.status()
        await rec.aclose()
        return st

    st = asyncio.run(run())
    vehicle.stop()
    assert not st.recording and st.last_stop.reason == "disarmed"
    meta = json.loads((tmp_path / st.last_stop.id / layout.SESSION_JSON).read_text())
    assert meta["trigger"] == "arm"
    assert meta["arming"]["reference_alt_m"] == 180.0
    assert meta["arming"]["home_lat_deg"] == 43.0021
    rows = read_csv(tmp_path / st.last_stop.id / layout.TELEMETRY_CSV)
    assert rows[-1]["heartbeat.armed"] == "0" and rows[0]["heartbeat.armed"] == "1"
    assert float(rows[-1]["t_s"]) - float(rows[0]["t_s"]) > 0.9  # kept the tail


def test_watching_for_arming_does_not_wake_the_event_loop_for_each_state(tmp_path):
    """The vehicle's state changes 100 times a second; its armed flag twice a flight.
    Only a change of the flag reaches the event loop (it looked 20 times a second)."""
    vehicle = FakeVehicle(rate_hz=100).start()
    rec = Recorder(tmp_path, vehicle.state, {}, options())
    selector = CountingSelector()

    async def run():
        await rec.open()
        await asyncio.sleep(0.3)  # the first state: disarmed, seen once
        turns = selector.turns
        await asyncio.sleep(1.5)
        quiet_turns = selector.turns - turns
        vehicle.armed = True  # still seen at once
        for _ in range(100):
            await asyncio.sleep(0.05)
            if rec.status().recording:
                break
        recording = rec.status().recording
        await rec.aclose()
        return quiet_turns, recording

    loop = asyncio.SelectorEventLoop(selector)
    try:
        quiet_turns, recording = loop.run_until_complete(run())
    finally:
        loop.close()
        vehicle.stop()
    assert recording
    assert quiet_turns <= 4  # the sleep's own turns; 30 and more before


def test_disk_nearly_full_stops_cleanly_with_reason(tmp_path, monkeypatch):
    real = shutil.disk_usage
    free = {"bytes": 10**9}
    monkeypatch.setattr(
        shutil, "disk_usage", lambda p: DiskUsage(real(p).total, real(p).used, free["bytes"])
    )
    cam = FakeCamera("front", FPS, make_jpegs(2)).start()
    vehicle = FakeVehicle().start()
    rec = Recorder(
        tmp_path,
        vehicle.state,
        {"front": cam.frames},
        options(auto_record_on_arm=False, limits=WriterLimits(min_free_bytes=50 * 10**6)),
    )

    async def run():
        await rec.open()
        await rec.start("test")
        await asyncio.sleep(1.0)
        free["bytes"] = 20 * 10**6  # the disk fills up
        for _ in range(200):
            await asyncio.sleep(0.05)
            if rec.recording_id is None:  # stopped and finalized
                break
        return rec.status()

    st = asyncio.run(run())
    cam.stop()
    vehicle.stop()
    assert not st.recording
    assert st.last_stop.reason.startswith("disk full") and "50 MB" in st.last_stop.reason
    folder = tmp_path / st.last_stop.id
    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    assert meta["status"] == "cut_short" and meta["stop_reason"] == st.last_stop.reason
    rows = read_csv(folder / layout.TELEMETRY_CSV)
    # The rows written before the disk filled are kept (how many a loaded box wrote in
    # that second is not the point).
    assert len(rows) == meta["quality"]["telemetry_rows"] > 0
    assert_rows_name_frames_on_disk(folder, rows)


def test_disk_too_slow_drops_are_counted(tmp_path, monkeypatch):
    """A disk that stalls for 1 s at every sync: small buffers overflow, drops are counted."""
    import os

    real_sync = os.fdatasync

    def slow_sync(fd):
        time.sleep(1.0)
        real_sync(fd)

    monkeypatch.setattr(os, "fdatasync", slow_sync)
    cam = FakeCamera("front", FPS, make_jpegs(2)).start()
    vehicle = FakeVehicle().start()
    rec = Recorder(
        tmp_path,
        vehicle.state,
        {"front": cam.frames},
        options(
            auto_record_on_arm=False,
            limits=WriterLimits(frame_queue=4, row_queue=8, min_free_bytes=1),
        ),
    )

    async def run():
        await rec.open()
        await rec.start("test")
        await asyncio.sleep(2.5)
        return await rec.stop()

    st = asyncio.run(run())
    cam.stop()
    vehicle.stop()
    folder = tmp_path / st.last_stop.id
    q = json.loads((folder / layout.SESSION_JSON).read_text())["quality"]
    fq = q["cameras"]["front"]
    frames = read_csv(folder / layout.frames_csv_relpath("front"))
    assert fq["frames_dropped_queue"] > 10 and fq["frames_written"] == len(frames)
    assert fq["frames_written"] + fq["frames_dropped"] == fq["frames_captured"]
    assert q["telemetry_rows_dropped"] > 5
    rows = read_csv(folder / layout.TELEMETRY_CSV)
    assert len(rows) == q["telemetry_rows"]
    assert_rows_name_frames_on_disk(folder, rows)


def assert_rows_name_frames_on_disk(folder: Path, rows: list[dict[str, str]]) -> None:
    """Some telemetry rows name a front frame, and every frame a row names is on disk (an
    empty set of names would pass the second half alone)."""
    named = {r["front.file"] for r in rows if r["front.file"]}
    missing = named - recorded_frames(folder, "front").keys()
    assert named and not missing, (len(named), sorted(missing)[:5])


def stalled_pack(folder: Path, camera: str = "front") -> int:
    """Make `camera`'s frames.mjpeg a FIFO that nobody reads yet, before the writer opens
    it: a real stall in the kernel, as a slow card gives. The writer's writev blocks once
    the pipe (64 kB) is full. Returns the reading end (non-blocking, so the open returns;
    closing it makes the next write fail with EPIPE)."""
    import os

    (folder / camera).mkdir()
    fifo = folder / layout.frames_pack_relpath(camera)
    os.mkfifo(fifo)
    return os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)


def drain(fd: int, until) -> bytes:
    """Read the FIFO `fd` until `until()` is true and nothing is left."""
    import os

    out = bytearray()
    while True:
        try:
            chunk = os.read(fd, 1 << 16)
        except BlockingIOError:
            if until():
                return bytes(out)
            time.sleep(0.01)
            continue
        if not chunk and until():
            return bytes(out)
        out += chunk


def big_jpeg(n: int = 100_000) -> bytes:
    """More than a pipe holds: the writer's writev of it stalls on an unread FIFO."""
    return b"\xff\xd8" + bytes(range(256)) * (n // 256) + b"\xff\xd9"


def test_a_write_stalled_past_the_stops_patience_is_waited_for(tmp_path, caplog):
    """A card can stall a write for seconds (cheap SD cards do, in fdatasync). The stop
    once gave the writer 10 s, then closed the files under it: the writer, resuming, died
    on a closed file (a traceback), and the rows and frames still queued were neither
    written nor counted, in a session reported complete. The stop waits (saying so), and
    everything queued reaches the files. The stall here is a real one: the camera's
    frame pack is a FIFO, whose write blocks in the kernel until a reader comes."""
    import os
    import threading

    from fpv_station.companion.recording.rows import RowFormatter, Sample
    from fpv_station.companion.recording.writer import SessionWriter

    t0 = time.monotonic()
    reader = stalled_pack(tmp_path)
    writer = SessionWriter(tmp_path, RowFormatter(("front",), t0), WriterLimits(min_free_bytes=0))
    died: list[BaseException] = []

    def record(args: threading.ExceptHookArgs) -> None:
        if args.exc_value is not None:
            died.append(args.exc_value)

    hook, threading.excepthook = threading.excepthook, record
    jpeg = big_jpeg()
    try:
        writer.start()
        for seq in (1, 2, 3):
            assert writer.put_frame("front", Frame("front", seq, jpeg, 320, 240, t0, time.time()))
        for k in range(10):
            assert writer.put_row(Sample(t0 + k / 30, time.time(), None, (None,)))
        # Patience 0.1 s (10 s in a session): the stall outlasts it many times over.
        closer = threading.Thread(target=writer.close, args=(0.1,))
        closer.start()
        closer.join(1.0)
        assert closer.is_alive()
        # The stall ends: the writer's writev goes on.
        assert drain(reader, lambda: not closer.is_alive()) == jpeg * 3
        closer.join(30)
        assert not closer.is_alive()
    finally:
        threading.excepthook = hook
        os.close(reader)
    assert died == []
    assert [int(r["seq"]) for r in read_csv(tmp_path / layout.frames_csv_relpath("front"))] == [
        1,
        2,
        3,
    ]
    assert len(read_csv(tmp_path / layout.TELEMETRY_CSV)) == writer.stats.rows_written == 10
    assert "still writing" in caplog.text


def test_writer_waits_for_its_batch_and_wakes_at_half_full(tmp_path):
    """Producers do not wake the writer per item (60 frames and 30 rows a second were as
    many wake-ups): what is queued waits for the batch timer, a queue at half its limit
    wakes the thread at once, and closing writes the rest. A batch's frames.csv rows go
    straight to the OS with its frames (no flush in this test but the close's)."""
    from fpv_station.companion.recording.rows import RowFormatter, Sample
    from fpv_station.companion.recording.writer import SessionWriter
    from tests.helpers import wait_until

    jpeg = make_jpegs(1)[0]
    t0 = time.monotonic()
    limits = WriterLimits(
        frame_queue=8, batch_interval_s=600.0, flush_interval_s=600.0, min_free_bytes=0
    )
    writer = SessionWriter(tmp_path, RowFormatter(("front",), t0), limits)
    writer.start()
    pack = tmp_path / layout.frames_pack_relpath("front")

    def frame(seq: int) -> Frame:
        return Frame("front", seq, jpeg, 320, 240, t0 + seq / 30, time.time())

    def listed() -> list[str]:
        return list(recorded_frames(tmp_path, "front"))

    try:
        for seq in (1, 2, 3):
            assert writer.put_frame("front", frame(seq))
        writer.put_row(Sample(t0 + 0.1, time.time(), None, (None,)))
        time.sleep(0.3)
        assert listed() == [] and pack.stat().st_size == 0  # below half: they wait
        assert writer.put_frame("front", frame(4))  # 4 of 8: the writer goes now
        assert wait_until(lambda: len(listed()) == 4, timeout=10), listed()
        assert pack.stat().st_size == 4 * len(jpeg)
        writer.put_frame("front", frame(5))
    finally:
        writer.close()
    assert listed() == [layout.frame_relpath("front", seq) for seq in range(1, 6)]
    assert pack.read_bytes() == jpeg * 5
    assert len(read_csv(tmp_path / layout.TELEMETRY_CSV)) == 1
    assert [r["seq"] for r in read_csv(tmp_path / layout.frames_csv_relpath("front"))] == [
        "1",
        "2",
        "3",
        "4",
        "5",
    ]


def test_a_failed_frame_write_keeps_the_batch_telemetry(tmp_path):
    """One batch holds frames, rows and packets; when the camera's pack fails the frame's
    write (here EPIPE: its FIFO lost its reader), the rows and packets queued with it are
    still written (the telemetry files are fine) and only the frames are counted lost."""
    import os

    from fpv_station.companion.recording.rows import RowFormatter, Sample
    from fpv_station.companion.recording.writer import SessionWriter

    jpeg = make_jpegs(1)[0]
    t0 = time.monotonic()
    limits = WriterLimits(batch_interval_s=600.0, flush_interval_s=600.0, min_free_bytes=0)
    reader = stalled_pack(tmp_path)
    writer = SessionWriter(tmp_path, RowFormatter(("front",), t0), limits)
    os.close(reader)  # the frame's write fails
    writer.start()
    try:
        assert writer.put_frame("front", Frame("front", 1, jpeg, 320, 240, t0, time.time()))
        for i in range(3):
            writer.put_row(Sample(t0 + 0.1 * i, time.time(), None, (None,)))
    finally:
        writer.close()  # the one batch: frames, rows and packets together
    assert writer.failure is not None and "Broken pipe" in writer.failure
    assert writer.stats.rows_written == 3 and writer.stats.rows_dropped == 0
    assert len(read_csv(tmp_path / layout.TELEMETRY_CSV)) == 3
    assert writer.stats.frames_written["front"] == 0
    assert writer.stats.frames_dropped_queue["front"] == 1
    assert read_csv(tmp_path / layout.frames_csv_relpath("front")) == []


def test_rows_reach_the_disk_only_after_the_frames_they_name(tmp_path):
    """A batch writes its frames (the pack, then their frames.csv rows) before its
    telemetry rows: a full CSV buffer reaches the OS in the middle of a batch, and a kill
    then must not leave rows on disk naming frames that are not, nor frames.csv rows
    naming bytes the pack does not hold. The pack here is a FIFO nobody reads: while the
    frame's write blocks in the kernel, no row of its batch may have been written."""
    import os

    from fpv_station.companion.recording.rows import RowFormatter, Sample
    from fpv_station.companion.recording.writer import SessionWriter

    jpeg = big_jpeg()
    t0 = time.monotonic()
    limits = WriterLimits(
        frame_queue=2, batch_interval_s=600.0, flush_interval_s=600.0, min_free_bytes=0
    )
    reader = stalled_pack(tmp_path)
    writer = SessionWriter(tmp_path, RowFormatter(("front",), t0), limits)
    csv_path = tmp_path / layout.TELEMETRY_CSV
    frames_csv = tmp_path / layout.frames_csv_relpath("front")
    header_bytes = csv_path.stat().st_size  # the header, flushed when the files open
    frames_header = frames_csv.stat().st_size
    writer.start()
    try:
        for k in range(600):  # more than the CSV's 64 kB buffer holds
            assert writer.put_row(Sample(t0 + k / 30, time.time(), None, (None,)))
        # One of 2: half the frame queue, so the writer takes the batch now.
        assert writer.put_frame("front", Frame("front", 1, jpeg, 320, 240, t0, time.time()))
        time.sleep(1.0)  # the writer is in the pack's writev by now (unless starved)
        assert writer.stats.rows_written == 0
        assert csv_path.stat().st_size == header_bytes
        assert frames_csv.stat().st_size == frames_header
    finally:
        closer = __import__("threading").Thread(target=writer.close)
        closer.start()
        assert drain(reader, lambda: not closer.is_alive()) == jpeg  # the write goes on
        closer.join(30)
        os.close(reader)
    assert writer.failure is None
    assert writer.stats.rows_written == 600 and writer.stats.frames_written["front"] == 1
    assert len(read_csv(csv_path)) == 600
    assert read_csv(frames_csv)[0]["offset"] == "0"


def test_a_rows_text_is_what_csv_writes_of_its_cells():
    """`RowFormatter.line` (what the writer writes, each group's text reused while the
    group is unchanged) and its `header_line` are exactly `csv.writer`'s text of the
    row's cells and of the columns, taken here
    plainly, column by column from `layout.state_fields`: for the
    states of a vehicle through the link's tracker (groups shared between rows, some
    changing every row, some not), a mode that needs quoting, no state yet, a camera
    without a frame, and no camera at all."""
    import io
    from dataclasses import replace

    from fpv_station.companion.link_settings import LinkSettings
    from fpv_station.companion.recording.rows import FrameRef, RowFormatter, Sample
    from fpv_station.companion.state_tracker import StateTracker
    from fpv_station.core.mavlink.framing import MavFramer
    from tests.mav_vehicle import MavVehicle

    vehicle, tracker, framer = MavVehicle(), StateTracker(), MavFramer()
    rates = {**LinkSettings().message_rates_hz, "HEARTBEAT": 1.0}
    due = dict.fromkeys(rates, 0.0)
    samples = [Sample(0.0, 1.7e9, None, (None, None))]
    for step in range(3000):  # 3 s of the vehicle, a row every 1/30 s
        t = step / 1000
        for name, hz in rates.items():
            if t >= due[name]:
                due[name] += 1 / hz
                vehicle.alt_m, vehicle.vx_mps = 10 + t, t % 3
                for msg in framer.feed(bytes(vehicle.build(name).pack(vehicle.mav))):
                    tracker.update(msg, t)
        if step % 33 == 0:
            state = tracker.state
            if step == 1980:
                state = replace(state, heartbeat=replace(state.heartbeat, mode='AUTO, "RTL"'))
            ref = FrameRef(step // 33, t - 0.01, 1.7e9 + t)
            samples.append(Sample(t, 1.7e9 + t, state, (ref, None if step % 2 else ref)))
    assert len({id(s.state.attitude) for s in samples[1:]}) > 50  # changing groups
    assert len({id(s.state.rc) for s in samples[1:]}) < len(samples) - 10  # shared ones

    def cells(s: Sample, cameras: tuple[str, ...]) -> list:
        out: list = [round(s.t_mono, 6), round(s.t_wall, 6)]
        state = s.state if s.state is not None else VehicleState()
        for group, field, index in layout.state_fields():
            value = getattr(getattr(state, group), field)
            if index is not None:
                value = value[index] if index < len(value) else None
            elif value is not None and (field == "t_mono" or field.endswith("_mono")):
                value = round(value, 6)  # t0 is 0 here
            if value is None:
                value = ""
            elif isinstance(value, bool):
                value = int(value)
            out.append(value)
        for cam, ref in zip(cameras, s.frames, strict=True):
            out += (
                ["", "", "", ""]
                if ref is None
                else [
                    ref.seq,
                    layout.frame_relpath(cam, ref.seq),
                    round(ref.t_wall, 6),
                    round(s.t_mono - ref.t_mono, 6),
                ]
            )
        return out

    for cameras in (("front", "bottom"), ()):
        text = RowFormatter(cameras, 0.0)
        expected = io.StringIO()
        csv.writer(expected).writerow(layout.telemetry_columns(cameras))
        assert text.header_line() == expected.getvalue()
        for s in samples:
            s = replace(s, frames=s.frames[: len(cameras)])
            expected = io.StringIO()
            csv.writer(expected).writerow(cells(s, cameras))
            assert text.line(s) == expected.getvalue()
    assert '"AUTO, ""RTL"""' in text.line(samples[61])
