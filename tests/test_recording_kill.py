"""A recording process killed with SIGKILL leaves a session readable to its last second."""

import json
import signal
import time
from pathlib import Path

import cv2
import httpx
import numpy as np
from pymavlink import mavutil

from fpv_station.companion.recording import layout
from tests.helpers import free_port, wait_until
from tests.processes import complete_rows, read_line, serve_args, spawn, station_up, terminate
from tests.recording_fakes import recorded_frames


def test_kill_9_keeps_last_second_and_next_start_marks_interrupted(tmp_path):
    proc = spawn(["-m", "tests.record_until_killed", str(tmp_path)])
    try:
        read_line(proc, "MARKED")
        sid = read_line(proc, "RECORDING ")
        time.sleep(3.0)
        killed_wall = time.time()
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    folder = tmp_path / sid
    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    assert meta["status"] == "recording"  # nobody closed it

    rows = complete_rows(folder / layout.TELEMETRY_CSV)
    last_wall = float(rows[-1]["wall_time"])
    assert killed_wall - last_wall < 1.0, killed_wall - last_wall  # readable to its last second
    assert len(rows) >= 70  # ~3 s at 30 Hz, minus at most the last second
    for cam in layout.CAMERAS:
        # Every frame a row on disk names is listed in frames.csv, its bytes in the pack:
        # the writer writes a batch's frames, then their rows, then the telemetry rows.
        refs = {r[f"{cam}.file"] for r in rows if r[f"{cam}.file"]}
        frames = recorded_frames(folder, cam)
        assert refs and refs <= frames.keys(), refs - frames.keys()
        assert all(j[:2] == b"\xff\xd8" and j[-2:] == b"\xff\xd9" for j in frames.values())
    mlog = mavutil.mavlink_connection(str(folder / layout.MAVLINK_TLOG))
    times = []
    while (m := mlog.recv_match()) is not None:
        times.append(m._timestamp)
    assert times and killed_wall - times[-1] < 1.0

    # The next start marks it interrupted, with the end taken from what is on disk.
    proc = spawn(["-m", "tests.record_until_killed", str(tmp_path)])
    try:
        assert read_line(proc, "MARKED").split() == [sid]
    finally:
        proc.kill()
        proc.wait()
    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    assert meta["status"] == "interrupted" and "interrupted" in meta["stop_reason"]
    assert meta["end_wall"] == last_wall and meta["quality"]["telemetry_rows"] == len(rows)
    frames = complete_rows(folder / layout.frames_csv_relpath("front"))
    assert meta["quality"]["cameras"]["front"]["frames_written"] == len(frames) > 60


def test_kill_9_of_the_server_and_restart(tmp_path):
    """The real CLI: start over REST, SIGKILL the server, start it again, see it marked."""
    port = free_port()
    env = {"FPV_RECORDING__SESSIONS_DIR": str(tmp_path), "FPV_RECORDING__MIN_FREE_MB": "0"}
    args = serve_args("none", port)
    base = f"http://127.0.0.1:{port}"

    proc = spawn(args, env)
    try:
        assert wait_until(lambda: station_up(base), timeout=60), "server did not start"
        sid = httpx.post(f"{base}/api/recording/start").json()["id"]
        time.sleep(2.0)
        killed_wall = time.time()
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        rows = complete_rows(tmp_path / sid / layout.TELEMETRY_CSV)
        assert killed_wall - float(rows[-1]["wall_time"]) < 1.0 and len(rows) >= 30
        proc = spawn(args, env)
        assert wait_until(lambda: station_up(base), timeout=60), "server did not restart"
        listed = {s["id"]: s for s in httpx.get(f"{base}/api/sessions").json()}
        assert listed[sid]["status"] == "interrupted"
        assert listed[sid]["telemetry_rows"] == len(rows)
    finally:
        terminate(proc)


def test_kill_9_of_the_station_on_the_twin_cuts_the_pack_after_its_last_listed_frame(tmp_path):
    """Session format 2: `serve --source sim` recording the twin's two
    cameras is killed. What a kill can leave: pack bytes after the last listed frame (the
    batch in its writev; here also made certain: a whole frame without a row and a cut
    one) and a cut last frames.csv row. The next start cuts the pack after its last
    listed frame, saying how many bytes, drops the cut row, and session.json counts what
    is on disk; every listed frame is a whole JPEG at its offset."""
    port = free_port()
    env = {
        "FPV_RECORDING__SESSIONS_DIR": str(tmp_path / "sessions"),
        "FPV_RECORDING__MIN_FREE_MB": "0",
        "XDG_CONFIG_HOME": str(tmp_path / "config"),
    }
    args = serve_args("sim", port)
    # The next start recovers every session whatever its link: without the twin, it
    # renders no cameras while it does.
    restart_args = serve_args("none", port)
    base = f"http://127.0.0.1:{port}"

    def listed(folder: Path, cam: str) -> list[dict[str, str]]:
        path = folder / layout.frames_csv_relpath(cam)
        return complete_rows(path) if path.exists() else []

    proc = spawn(args, env)
    try:
        assert wait_until(lambda: station_up(base), timeout=60), "server did not start"
        sid = httpx.post(f"{base}/api/recording/start", timeout=10).json()["id"]
        folder = tmp_path / "sessions" / sid
        assert wait_until(
            lambda: all(len(listed(folder, c)) >= 10 for c in layout.CAMERAS), timeout=60
        )
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    frames = {c: listed(folder, c) for c in layout.CAMERAS}
    ends = {c: int(f[-1]["offset"]) + int(f[-1]["bytes"]) for c, f in frames.items()}
    packs = {c: (folder / layout.frames_pack_relpath(c)).read_bytes() for c in layout.CAMERAS}
    # The front pack also gets a whole frame nobody listed and half a frame after it.
    front = packs["front"]
    newest = front[int(frames["front"][-1]["offset"]) : ends["front"]]
    with open(folder / layout.frames_pack_relpath("front"), "ab") as f:
        f.write(newest + newest[: len(newest) // 2])
    packs["front"] += newest + newest[: len(newest) // 2]
    frames_csv = folder / layout.frames_csv_relpath("front")
    if frames_csv.read_bytes().endswith(b"\n"):
        with open(frames_csv, "ab") as f:
            f.write(b"99999999,front/9999")  # a row cut mid-write
    tails = {c: len(packs[c]) - ends[c] for c in layout.CAMERAS}
    assert tails["front"] > len(newest)
    rows = complete_rows(folder / layout.TELEMETRY_CSV)
    packets = 0
    mlog = mavutil.mavlink_connection(str(folder / layout.MAVLINK_TLOG))
    while mlog.recv_msg() is not None:
        packets += 1

    proc = spawn(restart_args, env)
    try:
        assert wait_until(lambda: station_up(base), timeout=60), "server did not restart"
        listed_api = {s["id"]: s for s in httpx.get(f"{base}/api/sessions", timeout=10).json()}
        assert listed_api[sid]["status"] == "interrupted"
        # The route serves a listed frame out of the pack, byte for byte.
        r0 = frames["front"][0]
        got = httpx.get(f"{base}/api/sessions/{sid}/files/{r0['file']}", timeout=10)
        assert got.status_code == 200 and got.headers["content-type"] == "image/jpeg"
        assert (
            got.content == packs["front"][int(r0["offset"]) : int(r0["offset"]) + int(r0["bytes"])]
        )
    finally:
        terminate(proc)
    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    assert meta["status"] == "interrupted" and meta["format_version"] == 2
    assert meta["recovery"]["pack_tail_removed"] == tails
    assert meta["recovery"]["frames_added"] == dict.fromkeys(layout.CAMERAS, 0)
    assert meta["recovery"]["frame_rows_removed"] == dict.fromkeys(layout.CAMERAS, 0)
    assert meta["quality"]["telemetry_rows"] == len(rows)
    assert meta["quality"]["tlog_packets"] == packets
    t0 = meta["start_wall"]
    for cam in layout.CAMERAS:
        pack = (folder / layout.frames_pack_relpath(cam)).read_bytes()
        assert pack == packs[cam][: ends[cam]]
        assert (folder / layout.frames_csv_relpath(cam)).read_bytes().endswith(b"\n")
        assert listed(folder, cam) == frames[cam]
        for r in frames[cam]:
            data = pack[int(r["offset"]) : int(r["offset"]) + int(r["bytes"])]
            assert data.startswith(b"\xff\xd8") and data.endswith(b"\xff\xd9")
            image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
            assert (int(r["width"]), int(r["height"])) == (image.shape[1], image.shape[0])
        times = [float(r["t_s"]) for r in frames[cam]]
        assert times == sorted(times) and t0 + times[-1] < time.time()
        cq = meta["quality"]["cameras"][cam]
        assert cq["frames_written"] == len(frames[cam])
        assert cq["last_seq"] == int(frames[cam][-1]["seq"])
        assert cq["frames_captured"] == cq["frames_written"] + cq["frames_dropped"]
