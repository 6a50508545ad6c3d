"""Telemetry latency and CPU: MAVLink packet written -> WebSocket message received.

    python benchmarks/telemetry_latency.py [--clients 1 20 100] [--seconds 6] [--max-rate 50]
                                          [--slow-seconds 8]

Starts `fpv-station serve` as a real uvicorn process (so its CPU is measurable on its
own), a sender process writing ATTITUDE and GLOBAL_POSITION_INT at 250 Hz each (plus a
1 Hz HEARTBEAT) to the station's UDP port, and N WebSocket clients.
The clients run in worker processes (25 each) so that the measuring side does not
become the bottleneck. Each packet carries its own send time (CLOCK_MONOTONIC is shared by all processes on
Linux): ATTITUDE in `yawspeed` (float32 seconds since the run's epoch), GLOBAL_POSITION_INT
in `lat` (units of 10 us). A client records, for every group that changed since its last
message, received_at - sent_at. Printed per N: p50/p99/max added latency and the
server's CPU seconds per 1,000 packets.

Then the slow reader (a busy phone, goggles on weak Wi-Fi): one client with an 8 KB
receive buffer that reads one message per 100 ms, with `?ack=1` (acknowledging each
message) and without. Printed: the age of the attitude it reads, p50/p99/max.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.helpers import free_port  # noqa: E402
from tests.station_process import serve_station  # noqa: E402

RATE_HZ = 250.0
# Telemetry only: the 3D panel and recorder are measured by their own benchmarks.
SERVER_ENV = {
    "FPV_LINK__REQUEST_STREAMS": "false",
    "FPV_VISER__ENABLED": "false",
    "FPV_RECORDING__AUTO_RECORD_ON_ARM": "false",
}


def run_sender(port: int, epoch: float, seconds: float) -> None:
    """Child process: 250 Hz ATTITUDE + 250 Hz GLOBAL_POSITION_INT, 1 Hz HEARTBEAT."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    addr = ("127.0.0.1", port)

    def send(msg) -> None:
        sock.sendto(msg.pack(mav), addr)
        mav.seq = (mav.seq + 1) % 256

    def heartbeat():
        return mav.heartbeat_encode(
            mavlink.MAV_TYPE_QUADROTOR,
            mavlink.MAV_AUTOPILOT_PX4,
            81,
            3 << 16,
            mavlink.MAV_STATE_ACTIVE,
        )

    period = 1.0 / RATE_HZ
    t_next = time.monotonic()
    t_end = t_next + seconds
    next_hb = t_next
    i = 0
    sent = 0
    while t_next < t_end:
        now = time.monotonic()
        if now < t_next:
            time.sleep(t_next - now)
        if time.monotonic() >= next_hb:
            send(heartbeat())
            next_hb += 1.0
        i += 1
        t = time.monotonic()
        send(mav.attitude_encode(i, 0.1, 0.0, 0.0, 0.0, 0.0, t - epoch))
        t = time.monotonic()
        send(mav.global_position_int_encode(i, int((t - epoch) * 1e5), 0, 180000, 0, 0, 0, 0, 0))
        sent += 2
        t_next += period
    print(json.dumps({"sent": sent}), flush=True)


async def client(url: str, epoch: float, window: list[float], lat_s: list[float]) -> None:
    """One browser: records added latency for each group that changed, inside the window."""
    import websockets

    last_att = last_gp = None
    async with websockets.connect(url, max_size=None, compression=None) as ws:
        async for raw in ws:  # no per-message timeout task: it would cost more than the read
            now = time.monotonic()
            if now > window[1]:
                return
            s = json.loads(raw)["state"]
            att, gp = s["attitude"], s["global_position"]
            record = now >= window[0]
            if att["time_boot_ms"] is not None and att["time_boot_ms"] != last_att:
                last_att = att["time_boot_ms"]
                if record:
                    lat_s.append(now - (epoch + att["yawspeed_rad_s"]))
            if gp["time_boot_ms"] is not None and gp["time_boot_ms"] != last_gp:
                last_gp = gp["time_boot_ms"]
                if record:
                    lat_s.append(now - (epoch + gp["lat_deg"] * 1e7 / 1e5))


async def run_clients(url: str, epoch: float, n: int) -> None:
    """Child process: n clients; stdin gives the window, stdout returns the samples."""
    window = [float("inf"), float("inf")]
    lat_s: list[float] = []
    tasks = [asyncio.create_task(client(url, epoch, window, lat_s)) for _ in range(n)]
    await asyncio.sleep(0.5)
    print("ready", flush=True)
    line = await asyncio.to_thread(sys.stdin.readline)
    window[0], window[1] = (float(x) for x in line.split())
    await asyncio.wait(tasks, timeout=window[1] - time.monotonic() + 3)
    print(json.dumps(lat_s), flush=True)


def _spawn(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, __file__, *args],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )


@contextlib.contextmanager
def station_under_load(seconds: float):
    """A `fpv-station serve` process fed at RATE_HZ for `seconds` after a 1 s warm-up;
    yields (http_port, epoch, server process, t0 of the measured window)."""

    udp_port = free_port(socket.SOCK_DGRAM)
    tmp = tempfile.mkdtemp(prefix="fpv-bench-")
    sender = None
    try:
        with serve_station(
            ["--source", f"udpin:127.0.0.1:{udp_port}"],
            {**SERVER_ENV, "FPV_RECORDING__SESSIONS_DIR": tmp},
        ) as station:
            epoch = time.monotonic()
            warmup_s = 1.0

            def start_sender() -> float:
                nonlocal sender
                sender = _spawn(
                    "--sender", str(udp_port), str(epoch), str(seconds + warmup_s + 0.5)
                )
                return time.monotonic() + warmup_s

            yield station.port, epoch, station.popen, start_sender
            if sender is not None:
                sender.communicate(timeout=30)
    finally:
        if sender is not None and sender.poll() is None:
            sender.kill()
        shutil.rmtree(tmp, ignore_errors=True)


def measure(n_clients: int, seconds: float, max_rate: float, per_worker: int) -> dict:
    import psutil

    workers: list[subprocess.Popen] = []
    with station_under_load(seconds) as (http_port, epoch, server, start_sender):
        url = f"ws://127.0.0.1:{http_port}/ws/telemetry?max_rate={max_rate}"
        left = n_clients
        while left > 0:
            k = min(per_worker, left)
            workers.append(_spawn("--clients-worker", url, str(epoch), str(k)))
            left -= k
        for w in workers:
            assert w.stdout is not None and w.stdin is not None
            assert w.stdout.readline().strip() == "ready"
        t0 = start_sender()
        for w in workers:
            assert w.stdin is not None
            w.stdin.write(f"{t0} {t0 + seconds}\n")
            w.stdin.flush()
        time.sleep(max(t0 - time.monotonic(), 0))
        proc = psutil.Process(server.pid)
        cpu0 = sum(proc.cpu_times()[:2])
        time.sleep(seconds)
        cpu_s = sum(proc.cpu_times()[:2]) - cpu0
        packets = seconds * RATE_HZ * 2
        samples: list[float] = []
        for w in workers:
            assert w.stdout is not None
            samples += json.loads(w.stdout.readline())
            w.wait()
    ms = sorted(x * 1000 for x in samples)
    return {
        "clients": n_clients,
        "samples": len(ms),
        "p50_ms": statistics.median(ms),
        "p99_ms": ms[int(len(ms) * 0.99) - 1],
        "max_ms": ms[-1],
        "cpu_s_per_1000_packets": cpu_s / packets * 1000,
        "server_cpu_pct": cpu_s / seconds * 100,
    }


def measure_slow_reader(ack: bool, seconds: float) -> dict:
    """One client, 8 KB receive buffer, one message per 100 ms; the age of what it reads."""
    from tests.helpers import RawWsClient

    ages: list[float] = []
    with station_under_load(seconds) as (http_port, epoch, _server, start_sender):
        client = RawWsClient(
            f"http://127.0.0.1:{http_port}",
            f"/ws/telemetry?max_rate=1000&ack={int(ack)}",
            rcvbuf=8192,
        )
        t0 = start_sender()
        while time.monotonic() < t0 + seconds:
            m = client.recv_json()
            att = m["state"]["attitude"]
            if time.monotonic() >= t0 and att["time_boot_ms"] is not None:
                ages.append(time.monotonic() - (epoch + att["yawspeed_rad_s"]))
            time.sleep(0.1)  # the slow reader's own work per message
            if ack:
                client.send_text(json.dumps({"ack": m["version"]}))
        client.close()
    ms = sorted(a * 1000 for a in ages)
    return {
        "ack": ack,
        "samples": len(ms),
        "p50_ms": statistics.median(ms),
        "p99_ms": ms[max(int(len(ms) * 0.99) - 1, 0)],
        "max_ms": ms[-1],
    }


def link_cpu_us_per_packet() -> float:
    """CPU per packet of the link thread's work (framing, decode, state merge, publish)."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from fpv_station.companion.link import MavlinkLink
    from fpv_station.companion.link_settings import LinkSettings

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    packets = [bytes(mav.heartbeat_encode(2, 12, 81, 3 << 16, 4).pack(mav))]
    for i in range(5000):
        packets.append(bytes(mav.attitude_encode(i, 0.1, 0, 0, 0, 0, 0).pack(mav)))
        packets.append(bytes(mav.global_position_int_encode(i, 1, 2, 3, 4, 5, 6, 7, 8).pack(mav)))
    link = MavlinkLink(LinkSettings(source="udpin:127.0.0.1:9"))  # never started: no socket
    best = float("inf")
    for _ in range(5):
        t0 = time.process_time()
        for p in packets:
            link._on_bytes(p, time.monotonic())
        best = min(best, (time.process_time() - t0) / len(packets))
    return best * 1e6


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--sender":
        run_sender(int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]))
        return
    if len(sys.argv) > 1 and sys.argv[1] == "--clients-worker":
        asyncio.run(run_clients(sys.argv[2], float(sys.argv[3]), int(sys.argv[4])))
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--clients", type=int, nargs="+", default=[1, 20, 100])
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--max-rate", type=float, default=50.0, help="per-client cap (the default)")
    ap.add_argument("--per-worker", type=int, default=25, help="clients per client process")
    ap.add_argument("--slow-seconds", type=float, default=8.0, help="slow-reader run length")
    args = ap.parse_args()
    print(f"link thread: {link_cpu_us_per_packet():.1f} us CPU per packet (best of 5)")
    print(
        f"sender: ATTITUDE + GLOBAL_POSITION_INT at {RATE_HZ:.0f} Hz each; "
        f"clients capped at {args.max_rate:g} Hz; {args.seconds:g} s per run"
    )
    print(
        f"{'clients':>7} {'samples':>8} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8} "
        f"{'CPU s/1000 pkt':>15} {'server CPU %':>13}"
    )
    for n in args.clients:
        r = measure(n, args.seconds, args.max_rate, args.per_worker)
        print(
            f"{r['clients']:>7} {r['samples']:>8} {r['p50_ms']:>8.2f} {r['p99_ms']:>8.2f} "
            f"{r['max_ms']:>8.2f} {r['cpu_s_per_1000_packets']:>15.4f} {r['server_cpu_pct']:>13.1f}",
            flush=True,
        )
    print("slow reader: 8 KB receive buffer, one message per 100 ms (max_rate=1000)")
    print(f"{'mode':>8} {'samples':>8} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8}")
    for ack in (True, False):
        r = measure_slow_reader(ack, args.slow_seconds)
        mode = "ack=1" if ack else "no ack"
        print(
            f"{mode:>8} {r['samples']:>8} {r['p50_ms']:>8.1f} {r['p99_ms']:>8.1f} "
            f"{r['max_ms']:>8.1f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
