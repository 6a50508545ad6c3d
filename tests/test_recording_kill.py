"""A recording process killed with SIGKILL leaves a session readable to its last second."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
from pymavlink import mavutil

from companion.recording import layout
from tests.helpers import free_port, wait_until

ROOT = Path(__file__).resolve().parent.parent


def complete_rows(path: Path) -> list[dict[str, str]]:
    data = path.read_bytes()
    data = data[: data.rfind(b"\n") + 1]  # a cut last line is not a row
    return list(csv.DictReader(data.decode().splitlines()))


def spawn(args: list[str], env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, **(env or {})},
    )


def read_line(proc: subprocess.Popen, prefix: str, timeout: float = 20.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if line.startswith(prefix):
            return line[len(prefix) :].strip()
        if not line and proc.poll() is not None:
            break
    raise AssertionError(f"no '{prefix}' line from the recording process")


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
        refs = [r[f"{cam}.file"] for r in rows if r[f"{cam}.file"]]
        assert refs and all((folder / rel).stat().st_size > 0 for rel in refs)
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
    args = [
        "-m",
        "server",
        "serve",
        "--source",
        "none",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--no-3d",
        "--open",  # this test is about kill -9, not about the control token
    ]
    base = f"http://127.0.0.1:{port}"

    def up() -> bool:
        try:
            return httpx.get(f"{base}/api/health", timeout=1).status_code == 200
        except httpx.HTTPError:
            return False

    proc = spawn(args, env)
    try:
        assert wait_until(up, timeout=30), "server did not start"
        sid = httpx.post(f"{base}/api/recording/start").json()["id"]
        time.sleep(2.0)
        killed_wall = time.time()
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        rows = complete_rows(tmp_path / sid / layout.TELEMETRY_CSV)
        assert killed_wall - float(rows[-1]["wall_time"]) < 1.0 and len(rows) >= 30
        proc = spawn(args, env)
        assert wait_until(up, timeout=30), "server did not restart"
        listed = {s["id"]: s for s in httpx.get(f"{base}/api/sessions").json()}
        assert listed[sid]["status"] == "interrupted"
        assert listed[sid]["telemetry_rows"] == len(rows)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
