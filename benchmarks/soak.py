"""Soak: the station on the twin, recording, under 100 telemetry clients, 20 MJPEG viewers,
5 stalled clients, connection churn, 400 idle sockets, 30 slow-header clients and 10 3D
panel viewers, for N minutes.

    python benchmarks/soak.py [--minutes 10] [--telemetry 100] [--viewers 20]
                              [--idle 400] [--slow 30] [--viewers-3d 10]
                              [--trail-points N]

Idle sockets connect and send nothing; slow-header clients send a request's headers a
byte a second and never finish. The station closes both (server/listen.py); each comes
back at once, so the pressure on its connection table lasts the whole run. 3D viewers
come through the station's door (/3d/live and /3d/replay, relayed to the panels' viser
servers), report their camera once a second as a browser's client does while moved, and
read every frame of the scene.

Runs `fpv-station serve --source sim` in a subprocess (both cameras on image folders, so
the viewers cost what a USB camera's would), starts a recording, and holds the load from
this process over loopback. Prints at the start and at the end of the load: the server's
RSS, file descriptors and asyncio tasks (from /api/health and /proc), the live 3D trail's
points (`update_hz` a second while the vehicle moves, none while it sits, up to
`--trail-points`), per-client
telemetry message and MJPEG frame rates, and the session's rows against its rate.
Figures and load average go in docs/PERFORMANCE.md.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import functools
import json
import os
import platform
import resource
import socket
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx
import psutil
from websockets.asyncio.client import connect
from websockets.typing import Subprotocol

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.video import MjpegViewer, make_frames  # noqa: E402
from tests.helpers import viser_camera  # noqa: E402
from tests.station_process import serve_station  # noqa: E402

TOKEN = "soak-benchmark-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


class Counts:
    def __init__(self) -> None:
        self.telemetry: list[int] = []  # messages per client, since the last snapshot
        self.churned = 0
        self.churn_refused = 0
        self.idle_closed = 0  # idle sockets the station closed (each came back)
        self.slow_closed = 0  # slow-header clients the station closed (each came back)
        self.frames_3d: list[int] = []  # viser frames per 3D viewer, since the start
        self.viewers_3d = 0  # 3D viewers connected
        self.all_3d_in = asyncio.Event()  # every 3D viewer connected


async def telemetry_client(url: str, counts: Counts, i: int, stop: asyncio.Event) -> None:
    async with connect(url, max_size=1 << 20) as ws:
        while not stop.is_set():
            try:
                await asyncio.wait_for(ws.recv(), 1.0)
            except TimeoutError:
                continue
            counts.telemetry[i] += 1


def _spread(rates: list[float]) -> str:
    """Min and median of per-client rates; a load run with none of those clients says so."""
    if not rates:
        return "no clients"
    return f"min {min(rates):.1f}, median {statistics.median(rates):.1f}"


async def viewer_3d(url: str, counts: Counts, i: int, stop: asyncio.Event) -> None:
    """A 3D panel's viewer: its camera once a second, every frame of the scene read."""
    import viser

    camera = viser_camera()
    protocol = Subprotocol(f"viser-v{viser.__version__}")
    async with connect(url, subprotocols=[protocol], max_size=None) as ws:
        counts.viewers_3d += 1
        if counts.viewers_3d == len(counts.frames_3d):
            counts.all_3d_in.set()

        async def read() -> None:
            async for _ in ws:
                counts.frames_3d[i] += 1

        reader = asyncio.create_task(read())
        while not stop.is_set():
            await ws.send(camera)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), 1.0)
        reader.cancel()


async def stalled_clients(port: int, n: int, stop: asyncio.Event) -> None:
    """Open a WebSocket and an MJPEG stream each and never read (a frozen browser)."""
    socks = []
    for i in range(n):
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.setblocking(False)
        await asyncio.get_running_loop().sock_connect(s, ("127.0.0.1", port))
        if i % 2:
            s.send(b"GET /video/front.mjpg HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        else:
            s.send(
                b"GET /ws/telemetry HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
                b"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                b"Sec-WebSocket-Version: 13\r\n\r\n"
            )
        socks.append(s)
    await stop.wait()
    for s in socks:
        s.close()


async def _open(port: int) -> socket.socket | None:
    s = socket.socket()
    s.setblocking(False)
    try:
        await asyncio.wait_for(asyncio.get_running_loop().sock_connect(s, ("127.0.0.1", port)), 5)
    except (OSError, TimeoutError):
        s.close()
        return None
    return s


def _closed(s: socket.socket) -> bool:
    try:
        return s.recv(4096) == b""
    except BlockingIOError:
        return False
    except OSError:
        return True


async def idle_sockets(
    port: int, n: int, counts: Counts, stop: asyncio.Event, ready: asyncio.Event
) -> None:
    """Connections that never send a byte; each one closed is opened again. `ready` is
    set once all have been opened (the figures start from there)."""
    socks: list[socket.socket | None] = [None] * n
    while not stop.is_set():
        for i, s in enumerate(socks):
            if s is not None and _closed(s):
                s.close()
                socks[i] = s = None
                counts.idle_closed += 1
            if s is None:
                socks[i] = await _open(port)
        ready.set()
        await asyncio.sleep(1.0)
    for s in socks:
        if s is not None:
            s.close()


async def slow_headers(port: int, n: int, counts: Counts, stop: asyncio.Event) -> None:
    """Clients that send their headers a byte a second and never finish."""
    head = b"GET /api/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 100_000
    socks: list[socket.socket | None] = [None] * n
    sent = [0] * n
    while not stop.is_set():
        for i, s in enumerate(socks):
            if s is not None:
                try:
                    if _closed(s):
                        raise ConnectionResetError
                    s.send(head[sent[i] : sent[i] + 1])
                    sent[i] += 1
                    continue
                except OSError:
                    s.close()
                    counts.slow_closed += 1
            socks[i], sent[i] = await _open(port), 0
        await asyncio.sleep(1.0)
    for s in socks:
        if s is not None:
            s.close()


async def churn(url: str, counts: Counts, stop: asyncio.Event) -> None:
    """Clients that connect, take one message and leave, ten per second."""
    while not stop.is_set():
        try:
            async with connect(url) as ws:
                await asyncio.wait_for(ws.recv(), 5.0)
            counts.churned += 1
        except Exception:
            counts.churn_refused += 1
        await asyncio.sleep(0.1)


def server_figures(base: str, proc: psutil.Process) -> dict:
    health = httpx.get(f"{base}/api/health", timeout=10).json()
    rec = httpx.get(f"{base}/api/recording", timeout=10).json()
    panel = httpx.get(f"{base}/api/viser", timeout=10).json()
    return {
        "trail": panel["points"],
        "rss_mb": proc.memory_info().rss / 1e6,
        "fds": proc.num_fds(),
        "tasks": health["asyncio_tasks"],
        "status": health["status"],
        "rows": rec["telemetry_rows"],
        "frames": sum(rec["frames_written"].values()),
        "frames_dropped": sum(rec["frames_dropped"].values()),
        "t": time.monotonic(),
    }


async def load(args: argparse.Namespace, port: int, base: str, proc: psutil.Process) -> None:
    ws_url = f"ws://127.0.0.1:{port}/ws/telemetry"
    counts = Counts()
    counts.telemetry = [0] * args.telemetry
    counts.frames_3d = [0] * args.viewers_3d
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    tasks = [
        asyncio.create_task(telemetry_client(ws_url, counts, i, stop))
        for i in range(args.telemetry)
    ]
    viewers, transports = [], []
    for i in range(args.viewers):
        done = loop.create_future()
        transport, viewer = await loop.create_connection(
            functools.partial(MjpegViewer, done), "127.0.0.1", port
        )
        cam = "front" if i % 2 == 0 else "bottom"
        transport.write(f"GET /video/{cam}.mjpg HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
        viewers.append(viewer)
        transports.append(transport)
    for i in range(args.viewers_3d):
        url = f"ws://127.0.0.1:{port}/3d/{('live', 'replay')[i % 2]}"
        tasks.append(asyncio.create_task(viewer_3d(url, counts, i, stop)))
    if args.viewers_3d:  # in before the idle crowd: a full table would refuse them
        await asyncio.wait_for(counts.all_3d_in.wait(), 30)
    tasks.append(asyncio.create_task(stalled_clients(port, args.stalled, stop)))
    tasks.append(asyncio.create_task(churn(ws_url, counts, stop)))
    flood_ready = asyncio.Event()
    tasks.append(asyncio.create_task(idle_sockets(port, args.idle, counts, stop, flood_ready)))
    tasks.append(asyncio.create_task(slow_headers(port, args.slow, counts, stop)))
    await flood_ready.wait()
    await asyncio.sleep(args.warmup)

    def snapshot(label: str, since: dict | None) -> dict:
        fig = server_figures(base, proc)
        msgs, parts = list(counts.telemetry), [len(v.parts) for v in viewers]
        frames_3d = list(counts.frames_3d)
        if since is not None:
            dt = fig["t"] - since["t"]
            msg_rates = [(m - m0) / dt for m, m0 in zip(msgs, since["msgs"], strict=True)]
            fps = [(p - p0) / dt for p, p0 in zip(parts, since["parts"], strict=True)]
            rows_rate = (fig["rows"] - since["rows"]) / dt
            print(
                f"  telemetry msg/s per client: {_spread(msg_rates)}; MJPEG fps per viewer: "
                f"{_spread(fps)}; session rows/s {rows_rate:.1f} (rate {args.rate_hz:g} Hz)"
            )
            # The live panel's viewers (even ones): the replay's scene stands still.
            live = [(f - f0) / dt for f, f0 in zip(frames_3d, since["frames_3d"], strict=True)]
            if live[::2]:
                print(
                    f"  live 3D viewer frames/s: {_spread(live[::2])} ({len(frames_3d)} 3D "
                    f"viewers, {sum(frames_3d[1::2])} frames to the replay's)"
                )
        print(
            f"{label}: RSS {fig['rss_mb']:.1f} MB, fds {fig['fds']}, tasks {fig['tasks']}, "
            f"health {fig['status']}, rows {fig['rows']}, frames {fig['frames']} "
            f"(dropped {fig['frames_dropped']}), churned {counts.churned} "
            f"(refused {counts.churn_refused}), idle closed {counts.idle_closed}, slow "
            f"closed {counts.slow_closed}, 3D trail {fig['trail']} points, load "
            f"{os.getloadavg()[0]:.2f}",
            flush=True,
        )
        return {**fig, "msgs": msgs, "parts": parts, "frames_3d": frames_3d}

    start = snapshot("start", None)
    end_at = time.monotonic() + args.minutes * 60
    last = start
    while time.monotonic() < end_at:
        await asyncio.sleep(min(60.0, max(0.0, end_at - time.monotonic())))
        last = snapshot(f"t+{(time.monotonic() - start['t']) / 60:.1f} min", last)
    end = last
    growth = (end["rss_mb"] - start["rss_mb"]) / start["rss_mb"] * 100
    expected_rows = (end["t"] - start["t"]) * args.rate_hz
    print(
        f"RSS growth {growth:+.1f} %, fds {end['fds'] - start['fds']:+d}, tasks "
        f"{end['tasks'] - start['tasks']:+d}, rows {end['rows'] - start['rows']} of "
        f"~{expected_rows:.0f} expected at {args.rate_hz:g} Hz"
    )
    stop.set()
    for t in transports:
        t.close()
    await asyncio.gather(*tasks, return_exceptions=True)


def print_session_accounting(meta: dict, rate_hz: float) -> None:
    """Where the session's rows and frames went: lost (a bounded queue refused them: data
    loss) or never produced (the writer was held up past the state history, so what held
    at an instant is not known; the grid stays fixed and the instant is skipped, counted
    in telemetry_ticks_late)."""
    q = meta["quality"]
    expected = (meta["duration_s"] or 0.0) * rate_hz
    rows, late, dropped = (
        q["telemetry_rows"],
        q["telemetry_ticks_late"],
        q["telemetry_rows_dropped"],
    )
    print(
        f"rows: {rows} written of ~{expected:.0f} instants at {rate_hz:g} Hz over "
        f"{meta['duration_s']:.1f} s ({100 * rows / max(expected, 1):.1f} %); not produced: "
        f"{late} instants skipped (writer held up past the state history); lost: {dropped} "
        f"refused by the writer's queue; unaccounted: {expected - rows - late - dropped:+.0f}"
    )
    print(
        f"tlog: {q['tlog_packets']} packets written, {q['tlog_packets_dropped']} lost to a full "
        f"buffer"
    )
    for cam, c in q["cameras"].items():
        print(
            f"{cam}: {c['frames_written']} of {c['frames_captured']} frames written; missed "
            f"(gaps in the camera's sequence numbers) {c['frames_missed']}; lost to the "
            f"writer's full queue {c['frames_dropped_queue']}"
        )


def run(args: argparse.Namespace) -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)  # this side's sockets
    need = args.telemetry + args.viewers + args.stalled + args.idle + args.slow + 256
    need += args.viewers_3d
    if soft < need:
        resource.setrlimit(resource.RLIMIT_NOFILE, (min(need, hard), hard))
    tmp = Path(tempfile.mkdtemp(prefix="fpv-bench-soak-"))
    front, bottom = make_frames(tmp / "front", ".jpg"), make_frames(tmp / "bottom", ".jpg")
    cmd = ["--source", "sim", "--front", f"folder:{front}", "--bottom", f"folder:{bottom}"]
    env = {
        "FPV_SERVER__TOKEN": json.dumps(TOKEN),
        "FPV_VISER__ENABLED": json.dumps(args.viewers_3d > 0),
        "FPV_VISER__PORT": "0",
        "FPV_RECORDING__SESSIONS_DIR": json.dumps(str(tmp / "sessions")),
        "FPV_RECORDING__RATE_HZ": str(args.rate_hz),
    }
    if args.trail_points is not None:
        env["FPV_VISER__MAX_POINTS"] = str(args.trail_points)
    with serve_station(cmd, env, log_path=tmp / "server.log") as station:
        base, proc = station.base, station.process
        print(
            f"# fpv-station soak: {args.minutes:g} min, {args.telemetry} telemetry clients, "
            f"{args.viewers} MJPEG viewers, {args.stalled} stalled, churn 10/s, {args.idle} "
            f"idle sockets, {args.slow} slow-header clients, {args.viewers_3d} 3D viewers, "
            f"recording "
            f"at {args.rate_hz:g} Hz on the twin; machine {platform.machine()}, "
            f"{os.cpu_count()} cores, Python {platform.python_version()}"
        )
        r = httpx.post(f"{base}/api/recording/start", headers=AUTH, json={}, timeout=10)
        r.raise_for_status()
        asyncio.run(load(args, station.port, base, proc))
        stop = httpx.post(f"{base}/api/recording/stop", headers=AUTH, json={}, timeout=30)
        sid = stop.json()["last_stop"]["id"]
        meta = json.loads((tmp / "sessions" / sid / "session.json").read_text())
        print(f"session {sid}: status {meta['status']}, stop_reason {meta.get('stop_reason')}")
        print_session_accounting(meta, args.rate_hz)
    print(f"server log: {tmp / 'server.log'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--telemetry", type=int, default=100)
    ap.add_argument("--viewers", type=int, default=20)
    ap.add_argument("--stalled", type=int, default=5)
    ap.add_argument("--idle", type=int, default=400, help="sockets that never send")
    ap.add_argument("--slow", type=int, default=30, help="clients sending headers slowly")
    ap.add_argument("--viewers-3d", type=int, default=10, help="3D panel viewers (0: no viser)")
    ap.add_argument(
        "--trail-points",
        type=int,
        default=None,
        help="the live 3D trail's max_points (default: the station's); a small one fills "
        "within the run, to see the memory once the trail is full",
    )
    ap.add_argument("--rate-hz", type=float, default=50.0)
    ap.add_argument("--warmup", type=float, default=10.0)
    run(ap.parse_args())


if __name__ == "__main__":
    main()
