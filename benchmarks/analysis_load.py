"""Telemetry under anonymous analysis-figure load: WebSocket messages per second and the
longest gap between them, with no load, with cache-busting figure requests, and with
figure requests that are really all different.

    python benchmarks/analysis_load.py [--seconds 20] [--clients 4] [--root CHECKOUT]

Starts `fpv-station serve` (the checkout at --root, this one by default: run it on an
older commit's export to compare) on a session folder holding one synthetic A-to-B
session, feeds it MAVLink at 250 Hz (telemetry_latency.py's sender, in its own process)
and reads `/ws/telemetry` (50 Hz by default) in this process. The figure clients run in
another process so that they do not delay the reader:

    busted     GET .../birdseye.png?task=a-to-b&_=RANDOM   (the same figure, junk query)
    distinct   GET .../birdseye.png?task=a-to-b&margin_m=RANDOM   (a new figure each)

Printed per phase: telemetry msg/s, p99 and longest gap, the station process's own CPU
(% of one core; a worker process's is not in it) and the figure answers by status.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests import synthetic as syn  # noqa: E402
from tests.helpers import free_port  # noqa: E402
from tests.station_process import serve_station  # noqa: E402

SID = "20261122T040000Z_udp"
SENDER = ROOT / "benchmarks" / "telemetry_latency.py"
SERVER_ENV = {
    "FPV_LINK__REQUEST_STREAMS": "false",
    "FPV_VISER__ENABLED": "false",
    "FPV_RECORDING__AUTO_RECORD_ON_ARM": "false",
    "FPV_RECORDING__MIN_FREE_MB": "0",
}


async def load(base: str, kind: str, clients: int, seconds: float) -> None:
    """Child process: `clients` loops of figure requests for `seconds`; prints the counts."""
    import httpx

    plot = f"{base}/api/sessions/{SID}/analysis/birdseye.png?task=a-to-b"
    codes: Counter[str] = Counter()
    t_end = time.monotonic() + seconds

    async def one(client: httpx.AsyncClient) -> None:
        while time.monotonic() < t_end:
            junk = random.random()
            url = f"{plot}&_={junk}" if kind == "busted" else f"{plot}&margin_m={2 + junk}"
            try:
                r = await client.get(url, timeout=max(1.0, t_end - time.monotonic()))
                codes[str(r.status_code)] += 1
                if r.status_code == 503:
                    await asyncio.sleep(0.2)  # a client told "busy" tries again soon
            except httpx.HTTPError:
                codes["timeout"] += 1

    async with httpx.AsyncClient() as client:
        await asyncio.gather(*(one(client) for _ in range(clients)))
    print(json.dumps(codes), flush=True)


async def read_telemetry(url: str, seconds: float) -> dict:
    import websockets

    arrivals = []
    async with websockets.connect(url, max_size=None, compression=None) as ws:
        await ws.recv()  # the window opens at the first message, not at the connection
        t_end = time.monotonic() + seconds
        while (left := t_end - time.monotonic()) > 0:
            try:
                await asyncio.wait_for(ws.recv(), timeout=left)
            except TimeoutError:
                break
            arrivals.append(time.monotonic())
    gaps = [b - a for a, b in zip(arrivals, arrivals[1:])] or [seconds]
    return {
        "msg_per_s": round(len(arrivals) / seconds, 1),
        "gap_p99_ms": round(1000 * statistics.quantiles(gaps, n=100)[98], 1)
        if len(gaps) > 1
        else None,
        "gap_max_ms": round(1000 * max(gaps), 1),
    }


def phase(station, kind: str | None, clients: int, seconds: float) -> dict:
    base = station.base
    ws_url = base.replace("http", "ws") + "/ws/telemetry"
    loader = None
    if kind is not None:
        loader = subprocess.Popen(
            [sys.executable, __file__, "--load", base, kind, str(clients), str(seconds + 1)],
            stdout=subprocess.PIPE,
            text=True,
        )
        time.sleep(1.0)  # the clients are running when the window opens
    cpu0 = sum(station.process.cpu_times()[:2])
    figures = asyncio.run(read_telemetry(ws_url, seconds))
    # The station process's own CPU in the window (a worker process's is not in it).
    figures["station_cpu_pct"] = round(
        100 * (sum(station.process.cpu_times()[:2]) - cpu0) / seconds
    )
    if loader is not None:
        out, _ = loader.communicate(timeout=seconds + 120)
        figures["figures"] = json.loads(out.strip().splitlines()[-1])
    return figures


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--load":
        base, kind, clients, seconds = sys.argv[2:6]
        asyncio.run(load(base, kind, int(clients), float(seconds)))
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--clients", type=int, default=4)
    ap.add_argument("--root", type=Path, default=ROOT, help="the checkout whose station runs")
    args = ap.parse_args()

    udp_port = free_port(socket.SOCK_DGRAM)
    with tempfile.TemporaryDirectory(prefix="fpv-bench-analysis-") as tmp:
        syn.write_session(syn.a_to_b_flight(), Path(tmp) / SID, meta={"id": SID})
        env = {**SERVER_ENV, "FPV_RECORDING__SESSIONS_DIR": tmp}
        source = f"udpin:127.0.0.1:{udp_port}"
        with serve_station(["--source", source], env, root=args.root) as station:
            total = 3 * (args.seconds + 2) + 60
            sender = subprocess.Popen(
                [sys.executable, str(SENDER), "--sender", str(udp_port), "0", str(total)],
                stdout=subprocess.DEVNULL,
            )
            try:
                time.sleep(2.0)
                print(f"station: {args.root}, {os.cpu_count()} cores, {args.clients} clients")
                for load_kind in (None, "busted", "distinct"):
                    got = phase(station, load_kind, args.clients, args.seconds)
                    print(f"{load_kind or 'no load':9s} {json.dumps(got)}", flush=True)
            finally:
                sender.kill()
                sender.wait()


if __name__ == "__main__":
    main()
