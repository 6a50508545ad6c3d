"""SIGTERM under load: a real `fpv-station serve --source sim` with its
3D panels, recording, with telemetry clients and MJPEG viewers connected and reading,
then SIGTERM. Used by tests/test_shutdown.py (no traceback, the session complete) and
benchmarks/shutdown.py (how long the shutdown takes).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import signal
import socket
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
from websockets.asyncio.client import connect
from websockets.frames import Close, Frame, Opcode

from tests.helpers import free_port, wait_until
from tests.mjpeg_client import Viewer
from tests.processes import spawn, station_up

STALLED_REQUESTS = (
    b"GET /video/front.mjpg HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n",
    b"GET /ws/telemetry HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
    b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n",
)


@dataclass
class ShutdownRun:
    returncode: int | None  # None: it did not exit within the hang guard (then killed)
    exit_s: float  # SIGTERM to the process' exit
    output: str  # everything the server printed
    session: dict  # session.json of the recording that ran at the signal
    telemetry_msgs: int  # received by the clients before the signal (the load was real)
    video_parts: int


async def _telemetry_client(url: str, counts: list[int], i: int) -> None:
    with contextlib.suppress(Exception):  # ends when the server closes it
        async with connect(url, max_size=1 << 20) as ws:
            async for _ in ws:
                counts[i] += 1


async def _stalled_client(port: int, request: bytes) -> socket.socket:
    """A client that never reads (a frozen browser): the server's writes to it stall."""
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.setblocking(False)
    await asyncio.get_running_loop().sock_connect(s, ("127.0.0.1", port))
    s.send(request)
    return s


# A client's close frame (masked, as a client's must be): sent by a stalled WebSocket
# client whose tab is closed while the server's writes to it are backed up.
CLOSE_FRAME = Frame(Opcode.CLOSE, Close(1000, "").serialize()).serialize(mask=True)


async def _load(
    port: int,
    telemetry: int,
    viewers: int,
    stalled: int,
    closing: int,
    close_after_s: float,
    ready: threading.Event,
    stop,
) -> tuple:
    counts = [0] * telemetry
    url = f"ws://127.0.0.1:{port}/ws/telemetry"
    tasks = [asyncio.create_task(_telemetry_client(url, counts, i)) for i in range(telemetry)]
    watchers = [
        Viewer("127.0.0.1", port, f"/video/{('front', 'bottom')[i % 2]}.mjpg")
        for i in range(viewers)
    ]
    tasks += [asyncio.create_task(v.run(3600.0)) for v in watchers]
    socks = [await _stalled_client(port, STALLED_REQUESTS[i % 2]) for i in range(stalled)]
    closers = [await _stalled_client(port, STALLED_REQUESTS[1]) for _ in range(closing)]
    # Ready once every client got something (counters: nothing to await).
    while not (all(counts) and all(v.parts for v in watchers)) and not stop.is_set():  # noqa: ASYNC110
        await asyncio.sleep(0.1)
    ready.set()
    if closers:
        await asyncio.sleep(close_after_s)
        for s in closers:
            s.send(CLOSE_FRAME)
    await asyncio.to_thread(stop.wait)  # until the server is gone (the clients end with it)
    for s in socks + closers:
        s.close()
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    return sum(counts), sum(len(v.parts) for v in watchers)


def sigterm_under_load(
    tmp: Path,
    telemetry: int = 20,
    viewers: int = 10,
    stalled: int = 0,
    closing: int = 0,
    hold_s: float = 3.0,
    guard_s: float = 60.0,
) -> ShutdownRun:
    """Start the station, load it, record, SIGTERM it; `guard_s` only guards a hang.
    `stalled` clients stop reading; `closing` WebSocket clients stop reading and, halfway
    through `hold_s`, send their close frame (and read on no more)."""
    port = free_port()
    env = {
        "FPV_RECORDING__SESSIONS_DIR": str(tmp / "sessions"),
        "FPV_RECORDING__MIN_FREE_MB": "0",
        "FPV_VISER__PORT": "0",  # any free ports for both 3D panels
        "XDG_CONFIG_HOME": str(tmp / "config"),
        "PYTHONFAULTHANDLER": "1",  # a hang is ended with SIGABRT: every thread's stack
    }
    args = ["-m", "fpv_station.server", "serve", "--source", "sim", "--host", "127.0.0.1"]
    proc = spawn([*args, "--port", str(port), "--open"], env)
    lines: list[str] = []
    assert proc.stdout is not None
    out = proc.stdout
    reader = threading.Thread(target=lambda: lines.extend(out), daemon=True)
    reader.start()
    base = f"http://127.0.0.1:{port}"
    ready, gone = threading.Event(), threading.Event()
    result: list[tuple] = []
    loader = threading.Thread(
        target=lambda: result.append(
            asyncio.run(_load(port, telemetry, viewers, stalled, closing, hold_s / 2, ready, gone))
        ),
        daemon=True,
    )
    try:
        if not wait_until(lambda: station_up(base), timeout=guard_s):
            raise AssertionError("the station did not start:\n" + "".join(lines))
        sid = httpx.post(f"{base}/api/recording/start", timeout=10).json()["id"]
        loader.start()
        if not ready.wait(guard_s):
            raise AssertionError("the clients got nothing:\n" + "".join(lines))
        time.sleep(hold_s)
        t0 = time.monotonic()
        proc.terminate()
        try:
            proc.wait(guard_s)
        except subprocess.TimeoutExpired:
            pass
        exit_s = time.monotonic() - t0
    finally:
        gone.set()
        if proc.poll() is None:
            proc.send_signal(signal.SIGABRT)
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            returncode = None
        else:
            returncode = proc.returncode
        loader.join(30)
        reader.join(10)
    msgs, parts = result[0] if result else (0, 0)
    session = json.loads((tmp / "sessions" / sid / "session.json").read_text())
    return ShutdownRun(returncode, exit_s, "".join(lines), session, msgs, parts)
