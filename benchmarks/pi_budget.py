"""The Pi's budget: CPU per thread and per component, RSS and start-up of the whole station.

    python benchmarks/pi_budget.py [--seconds 20] [--warmup 5] [--repeat 2] [--3d both|on|off]
                                   [--rates default|small-pi|both] [--no-profile]
                                   [--autopilot-streams requested|px4-onboard|both]

Runs the real-Pi configuration on this machine, as `fpv-station serve` in a subprocess
(tests/station_process.py):
- the test vehicle (tests/mav_vehicle.py) over UDP, at the rates the station asks for
  (SET_MESSAGE_INTERVAL: about 140 packets/s; `--rates small-pi`: the settings a Pi 3 or
  Zero 2 W team uncomments in /etc/fpv-station/config.toml, server.install_service:
  about 75 packets/s and the pages at 25 messages/s; `--autopilot-streams px4-onboard`:
  plus what PX4 streams unasked on a link in MAV_X_MODE Onboard, about 210 packets/s);
- two USB MJPEG cameras at 640x480, 30 fps, through the station's own V4L2 source and its
  passthrough (the grabber is simulated at OpenCV's VideoCapture: usb_mjpeg_camera.py);
- recording on (telemetry, tlog and both videos);
- two telemetry WebSocket clients that acknowledge their messages as the pages do
  (`?ack=2`, an ack every second message; `--telemetry-ack 1`: one per message;
  `--telemetry-ack 0` or `--no-telemetry-ack`: clients that only read), and
  two MJPEG viewers per camera, in this process;
- the 3D panel on, off, or both runs side by side. "On": the pilot page's GET /api/viser
  starts its viser servers once the station is ready (`--no-visit`: not), nobody looks.

The stations start from bytecode, as an installed one does (`prepare_checkout`).

Printed per run: start-up (spawn to the first healthy /api/health), the process's CPU in
% of one core over the window (CPU seconds from /proc, not wall time), RSS (when ready and
at the end; at the end also its anonymous part: the mapped libraries' pages count in RSS
by whole page-cache folios, so a freshly `pip install`ed environment reads about 20 MB
more on this kernel until those files are read back from disk), CPU per
thread (/proc/PID/task/TID/stat; names from `py-spy dump`), and per component: link,
cameras, fan-out (frames and telemetry to clients), recorder, web (the rest of the event
loop), 3D panel, other. The event loop thread is split between fan-out, 3D panel and web by
py-spy's samples of it that hold the GIL (`--no-profile`: not split); the busiest
functions (self time in those samples, every thread) follow. `--count-instructions`
adds perf's count of the instructions the station ran and the cycles they took, in all
and per thread: the work itself, which the host under a VM does not change, apart from
what the host made of it (cycles per instruction), and the share of a core the
user-space part would take at the speed of warm Python on this host
(host_wake_cost.warm_speed, just after the window): the rest of the CPU figure is what
waking costs here.
Figures, machine and load average go in docs/PERFORMANCE.md.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import compileall
import json
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.host_wake_cost import (  # noqa: E402
    perf_counts_per_thread,
    probe_in_subprocess,
    warm_speed,
)
from benchmarks.video import MjpegViewer, make_frames  # noqa: E402
from fpv_station.server.install_service import small_pi_toml  # noqa: E402
from tests.mav_vehicle import PX4_ONBOARD_RATES_HZ, MavVehicle  # noqa: E402
from tests.station_process import StationProcess, serve_station  # noqa: E402

TOKEN = "pi-budget-token"
PAGE_ACK_WINDOW = 2  # web/telemetry.js's ACK_WINDOW: the pages' ?ack=
T = TypeVar("T")
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
COMPONENTS = ("link", "cameras", "fan-out", "recorder", "web", "3D panel", "other")
# Event-loop samples whose stack passes through these files are fan-out, the rest web.
FANOUT_FILES = (
    "server/video_fanout.py",
    "server/routes/video.py",
    "server/routes/telemetry.py",
    "server/telemetry_json.py",
    "server/telemetry_pump.py",
)
PANEL_FILES = ("server/trajectory3d/", "/viser/")  # the live 3D panel's steps on the loop


@dataclass
class ThreadInfo:
    tid: int
    name: str
    stack: str = ""  # from py-spy dump, to tell viser's threads by their code


@dataclass
class Run:
    label: str
    ready_s: float
    ready_cpu_s: float
    seconds: float
    cpu_s: float
    rss_mb: float  # at the end of the window
    # Of it, the process's own memory (the rest is the mapped files' pages: the libraries'
    # code, counted in whole page-cache folios, so it depends on how they were cached).
    rss_anon_mb: float
    rss_ready_mb: float  # when first healthy, before any client (or the 3D panel's visit)
    load: tuple[float, float]  # 1-min load average at the window's start and end
    threads: list[tuple[ThreadInfo, float]]  # (thread, CPU seconds in the window)
    thread_sys_s: dict[int, float]  # system (kernel) seconds of each thread in the window
    # Context switches of each thread in the window: (voluntary, involuntary). Voluntary:
    # it blocked (a wait for I/O, a timer, a lock or the GIL), so about one wake-up each.
    switches: dict[int, tuple[int, int]]
    host_wake_us: tuple[float, float]  # host_wake_cost.py before and after the window
    components: dict[str, float]
    # perf's counts over the window per thread id, per second: instructions and cycles,
    # user and kernel ("instructions:u", ...); empty without perf or hardware counters.
    thread_counters: dict[int, dict[str, float]] = field(default_factory=dict)
    # User instructions warm Python runs here per CPU second, after the window (perf).
    warm_insn_per_s: float | None = None
    top: list[tuple[str, float]] = field(default_factory=list)  # (function, share of samples)
    packets_per_s: float = 0.0
    fps: dict[str, float] = field(default_factory=dict)
    telemetry_msgs_per_s: list[float] = field(default_factory=list)
    viewer_fps: list[float] = field(default_factory=list)

    @property
    def counters(self) -> dict[str, float]:
        """The process's counts a second: its threads' summed."""
        total: collections.Counter[str] = collections.Counter()
        for events in self.thread_counters.values():
            total.update(events)
        return dict(total)


# -- /proc -----------------------------------------------------------------------------


def _per_thread(pid: int, name: str, parse: Callable[[str], T]) -> dict[int, T]:
    """`parse` of /proc/PID/task/TID/`name` for each live thread of `pid`."""
    out = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            text = (task / name).read_text()
        except OSError:
            continue  # ended meanwhile
        out[int(task.name)] = parse(text)
    return out


def _cpu_s(stat: str) -> tuple[float, float]:
    fields = stat[stat.rindex(")") + 2 :].split()
    return int(fields[11]) / CLOCK_TICKS, int(fields[12]) / CLOCK_TICKS


def _switches(status: str) -> tuple[int, int]:
    counts = dict(line.split(":\t") for line in status.splitlines() if "ctxt_switches" in line)
    return int(counts["voluntary_ctxt_switches"]), int(counts["nonvoluntary_ctxt_switches"])


def thread_cpu_s(pid: int) -> dict[int, tuple[float, float]]:
    """CPU seconds (user, system) of each live thread of `pid`."""
    return _per_thread(pid, "stat", _cpu_s)


def thread_switches(pid: int) -> dict[int, tuple[int, int]]:
    """(voluntary, involuntary) context switches of each live thread of `pid`."""
    return _per_thread(pid, "status", _switches)


def process_cpu_s(pid: int) -> float:
    """CPU seconds of the whole process, ended threads included."""
    stat = Path(f"/proc/{pid}/stat").read_text()
    fields = stat[stat.rindex(")") + 2 :].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def rss_mb(pid: int, field: str = "VmRSS") -> float:
    """`VmRSS` (all resident memory) or `RssAnon` (the process's own, without mapped
    files) from /proc/PID/status, in MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def comm(pid: int, tid: int) -> str:
    try:
        return Path(f"/proc/{pid}/task/{tid}/comm").read_text().strip()
    except OSError:
        return "?"


# -- py-spy ----------------------------------------------------------------------------


def py_spy() -> str | None:
    found = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    return found if Path(found).exists() else None


def thread_names(pid: int) -> dict[int, ThreadInfo]:
    """Python thread names by OS thread id (py-spy dump); /proc's comm where unknown."""
    infos = {tid: ThreadInfo(tid, comm(pid, tid)) for tid in thread_cpu_s(pid)}
    spy = py_spy()
    if spy is None:
        return infos
    dump = subprocess.run(
        [spy, "dump", "--pid", str(pid), "--nonblocking"], capture_output=True, text=True
    ).stdout
    current: ThreadInfo | None = None
    for line in dump.splitlines():
        m = re.match(r'Thread (\d+) \((\w+)\): "(.*)"', line)
        if m:
            current = infos.setdefault(int(m[1]), ThreadInfo(int(m[1]), m[3]))
            current.name = m[3]
        elif current is not None:
            current.stack += line + "\n"
    return infos


def start_profile(pid: int, seconds: float, out: Path, rate: int) -> subprocess.Popen | None:
    spy = py_spy()
    if spy is None:
        return None
    return subprocess.Popen(
        [spy, "record", "--pid", str(pid), "--duration", str(int(seconds)), "--rate", str(rate)]
        + ["--format", "raw", "--threads", "--gil", "--nonblocking", "--full-filenames"]
        + ["-o", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


COUNTED = ("instructions:u", "instructions:k", "cycles:u", "cycles:k")


def start_counting(pid: int, out: Path) -> subprocess.Popen | None:
    """`perf stat` on each of the station's threads for the window: the instructions it runs,
    which the host under a VM does not change, and the cycles they took, which it does
    (cold caches after each wake-up). None where perf is not installed. Under a VM the
    counters are saved and restored at every context switch, which the CPU figure then
    includes (17.7 against about 13 % here): compare runs that counted with runs that did."""
    perf = shutil.which("perf")
    if perf is None:
        return None
    return subprocess.Popen(
        [perf, "stat", "--per-thread", "-x,", "-e", ",".join(COUNTED), "-p", str(pid)]
        + ["-o", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def stop_counting(perf: subprocess.Popen | None, out: Path) -> dict[int, dict[str, float]]:
    """The counts of `start_counting`, per thread id; empty where the machine has no
    such counters (perf prints "<not supported>")."""
    if perf is None:
        return {}
    perf.send_signal(signal.SIGINT)
    try:
        perf.wait(10)
    except subprocess.TimeoutExpired:
        perf.kill()
        return {}
    return perf_counts_per_thread(out.read_text()) if out.exists() else {}


def read_profile(path: Path) -> dict[int, list[tuple[list[str], int]]]:
    """py-spy raw samples: OS thread id -> [(frames, outermost first; count)]."""
    samples: dict[int, list[tuple[list[str], int]]] = collections.defaultdict(list)
    if not path.exists():
        return samples
    for line in path.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        m = re.match(r"thread \((\d+)\): [^;]*;?(.*)", stack)
        if m and count.isdigit():
            samples[int(m[1])].append((m[2].split(";") if m[2] else [], int(count)))
    return samples


# -- components -------------------------------------------------------------------------


def component_of(info: ThreadInfo, loop_tid: int) -> str:
    name = info.name
    if info.tid == loop_tid:
        return "web"
    if name.startswith("mavlink"):
        return "link"
    if name.startswith("camera-"):
        return "cameras"
    if name.startswith("recorder-"):
        return "recorder"
    if "viser" in info.stack or "websockets" in info.stack:
        return "3D panel"
    return "other"


def loop_component(frames: list[str]) -> str:
    """Who an event-loop sample works for: the 3D panel, fan-out, or web (the rest)."""
    if any(f in s for s in frames for f in PANEL_FILES):
        return "3D panel"
    if any(f in s for s in frames for f in FANOUT_FILES):
        return "fan-out"
    return "web"


def split_components(
    threads: list[tuple[ThreadInfo, float]], loop_tid: int, samples: dict
) -> dict[str, float]:
    out = dict.fromkeys(COMPONENTS, 0.0)
    for info, cpu in threads:
        comp = component_of(info, loop_tid)
        loop_samples = samples.get(loop_tid) if comp == "web" else None
        if loop_samples:
            total = sum(n for _, n in loop_samples)
            for frames, n in loop_samples:
                out[loop_component(frames)] += cpu * n / total
        else:
            out[comp] += cpu
    return out


def top_functions(samples: dict, n: int = 12) -> list[tuple[str, float]]:
    """The innermost frame of each sample (self time), as a share of all samples."""
    counts: collections.Counter[str] = collections.Counter()
    for per_thread in samples.values():
        for frames, k in per_thread:
            if frames:
                counts[_short(frames[-1])] += k
    total = sum(counts.values()) or 1
    return [(fn, k / total) for fn, k in counts.most_common(n)]


def _short(frame: str) -> str:
    root = str(ROOT) + "/"
    frame = frame.replace(root, "")
    return re.sub(r"\(/.*?(site-packages|lib/python3\.\d+)/", "(", frame)


# -- start-up as installed ---------------------------------------------------------------

# The folders `pip install` puts on a Pi (pyproject.toml's package-dir), plus the
# benchmark's grabber.
INSTALLED_PACKAGES = (
    "fpv_station",
    "core",
    "companion",
    "twin",
    "analysis",
    "learn",
    "server",
    "benchmarks",
)


def prepare_checkout(root: Path) -> None:
    """Write the bytecode of `root`'s packages, as `pip install` does on a Pi (and in the
    Docker image). Without it a checkout run with PYTHONDONTWRITEBYTECODE (as here)
    compiles every module it imports at each start: 0.1-0.2 CPU s that no installed
    station pays. The station then reads the bytecode, whatever that variable says.
    Another checkout (`--baseline`) gets this grabber first, whatever it has of its own."""
    if root != ROOT:
        shutil.copy(ROOT / "benchmarks" / "usb_mjpeg_camera.py", root / "benchmarks")
    for package in INSTALLED_PACKAGES:
        if (root / package).is_dir():  # a baseline from before the namespace has no fpv_station/
            compileall.compile_dir(root / package, quiet=1)


# -- the clients ---------------------------------------------------------------------------


async def clients(
    port: int, seconds: float, warmup: float, telemetry: int, viewers: int, ack: int = 0
):
    """Telemetry WebSocket clients and MJPEG viewers for warmup + seconds; their rates.
    `ack`: the telemetry clients ask for at most `ack` messages in flight and acknowledge
    when that many are unacknowledged, as the pages do (web/telemetry.js: ?ack=2)."""
    from websockets.asyncio.client import connect

    loop = asyncio.get_running_loop()
    counts = [0] * telemetry
    stop = asyncio.Event()
    url = f"ws://127.0.0.1:{port}/ws/telemetry" + (f"?ack={ack}" if ack else "")

    async def telemetry_client(i: int) -> None:
        async with connect(url, max_size=1 << 20) as ws:
            while not stop.is_set():
                try:
                    message = await asyncio.wait_for(ws.recv(), 1.0)
                except TimeoutError:
                    continue
                counts[i] += 1
                if ack and counts[i] % ack == 0:
                    await ws.send(json.dumps({"ack": json.loads(message)["version"]}))

    tasks = [asyncio.create_task(telemetry_client(i)) for i in range(telemetry)]
    mjpeg, transports = [], []
    for cam in ("front", "bottom"):
        for _ in range(viewers):
            transport, viewer = await loop.create_connection(
                lambda: MjpegViewer(loop.create_future()), "127.0.0.1", port
            )
            transport.write(f"GET /video/{cam}.mjpg HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
            mjpeg.append(viewer)
            transports.append(transport)
    await asyncio.sleep(warmup)
    c0, p0 = list(counts), [len(v.parts) for v in mjpeg]
    await asyncio.sleep(seconds)
    msgs = [(c - b) / seconds for c, b in zip(counts, c0, strict=True)]
    fps = [(len(v.parts) - b) / seconds for v, b in zip(mjpeg, p0, strict=True)]
    stop.set()
    for t in transports:
        t.close()
    await asyncio.gather(*tasks, return_exceptions=True)
    return msgs, fps


# -- one run ---------------------------------------------------------------------------------


def one_run(
    args: argparse.Namespace,
    tmp: Path,
    with_3d: bool,
    label: str,
    small_pi: bool = False,
    px4_onboard: bool = False,
) -> Run:
    front, bottom = tmp / "front", tmp / "bottom"
    sessions = tmp / f"sessions-{label}"
    vehicle = MavVehicle("udp", rates_hz=PX4_ONBOARD_RATES_HZ if px4_onboard else None).start()
    cmd = [
        *("--source", vehicle.station_source),
        *("--front", f"v4l2:{front}?fourcc=MJPG", "--bottom", f"v4l2:{bottom}?fourcc=MJPG"),
        *("--viser-port", "0", "--sessions-dir", str(sessions)),
        *(() if with_3d else ("--no-3d",)),
    ]
    if small_pi:
        config = tmp / "small-pi.toml"
        config.write_text(small_pi_toml())
        cmd += ["--config", str(config)]
    env = {"FPV_SERVER__TOKEN": json.dumps(TOKEN)}
    launcher = ("-m", "benchmarks.usb_mjpeg_camera")
    root = args.station_root or ROOT
    try:
        with serve_station(cmd, env, launcher=launcher, root=root) as station:
            return measure(args, station, label)
    finally:
        vehicle.stop()


def measure(args: argparse.Namespace, station: StationProcess, label: str) -> Run:
    pid = station.popen.pid
    rss_ready = rss_mb(pid)
    auth = {"Authorization": f"Bearer {TOKEN}"}
    if not args.no_visit:  # the pilot page asks for the 3D panel at once: it starts then
        httpx.get(f"{station.base}/api/viser", timeout=30).raise_for_status()
    if not args.no_record:
        httpx.post(
            f"{station.base}/api/recording/start", headers=auth, json={}, timeout=10
        ).raise_for_status()
    # The clients connect and warm up; the window starts after `warmup` s.
    result: dict = {}

    async def drive() -> None:
        task = asyncio.create_task(
            clients(
                station.port,
                args.seconds,
                args.warmup,
                args.telemetry_clients,
                args.viewers,
                args.telemetry_ack,
            )
        )
        await asyncio.sleep(args.warmup)
        result["start"] = await asyncio.to_thread(window_start, station, args)
        result["rates"] = await task
        result["end"] = await asyncio.to_thread(window_end, station, result["start"][-1])

    asyncio.run(drive())
    (cpu0, threads0, sw0, status0, t0, load0, host0, spy, perf) = result["start"]
    (cpu1, threads1, sw1, status1, t1, load1, host1, counts, warm) = result["end"]
    seconds = t1 - t0
    profile = profile_path(station)
    samples: dict = {}
    if spy is not None:
        spy.wait(30)
        samples = read_profile(profile)
        if args.profile_out is not None and profile.exists():
            args.profile_out.mkdir(parents=True, exist_ok=True)
            name = re.sub(r"\W+", "-", label).strip("-")
            shutil.copy(profile, args.profile_out / f"py-spy-{name}.txt")
    names = thread_names(pid)
    user0 = {tid: u for tid, (u, _) in threads0.items()}
    sys0 = {tid: s for tid, (_, s) in threads0.items()}
    thread_sys = {tid: s - sys0.get(tid, 0.0) for tid, (_, s) in threads1.items()}
    threads = sorted(
        (
            (
                names.get(tid, ThreadInfo(tid, comm(pid, tid))),
                u - user0.get(tid, 0.0) + thread_sys[tid],
            )
            for tid, (u, _) in threads1.items()
        ),
        key=lambda x: -x[1],
    )
    cams = httpx.get(f"{station.base}/api/cameras", timeout=10).json()["cameras"]
    rec = httpx.post(f"{station.base}/api/recording/stop", headers=auth, json={}, timeout=30)
    if not args.no_record and not rec.json().get("last_stop"):
        print(f"# recording stop: {rec.text[:300]}", file=sys.stderr)
    packets = status1["link"]["packets"] - status0["link"]["packets"]
    msgs, fps = result["rates"]
    return Run(
        label=label,
        ready_s=station.ready_s,
        ready_cpu_s=station.ready_cpu_s,
        seconds=seconds,
        cpu_s=cpu1 - cpu0,
        rss_mb=rss_mb(pid),
        rss_anon_mb=rss_mb(pid, "RssAnon"),
        rss_ready_mb=rss_ready,
        load=(load0, load1),
        threads=threads,
        thread_sys_s=thread_sys,
        switches={
            tid: (v - sw0.get(tid, (0, 0))[0], n - sw0.get(tid, (0, 0))[1])
            for tid, (v, n) in sw1.items()
        },
        host_wake_us=(host0, host1),
        thread_counters={
            tid: {event: n / seconds for event, n in events.items()}
            for tid, events in counts.items()
        },
        warm_insn_per_s=warm,
        components=split_components(threads, pid, samples),
        top=top_functions(samples),
        packets_per_s=packets / seconds,
        fps={c["name"]: c["delivered_fps"] for c in cams},
        telemetry_msgs_per_s=msgs,
        viewer_fps=fps,
    )


def profile_path(station: StationProcess) -> Path:
    return station.log_path.with_name("profile.txt")  # each station has its own folder


def counters_path(station: StationProcess) -> Path:
    return station.log_path.with_name("perf-stat.txt")


def window_start(station: StationProcess, args: argparse.Namespace):
    pid = station.popen.pid
    host = probe_in_subprocess()  # the host as the window starts, the clients running
    status = httpx.get(f"{station.base}/api/status", timeout=10).json()
    spy = (
        None
        if args.no_profile
        else start_profile(pid, args.seconds, profile_path(station), args.profile_rate)
    )
    perf = start_counting(pid, counters_path(station)) if args.count_instructions else None
    return (
        process_cpu_s(pid),
        thread_cpu_s(pid),
        thread_switches(pid),
        status,
        time.monotonic(),
        os.getloadavg()[0],
        host,
        spy,
        perf,
    )


def window_end(station: StationProcess, perf: subprocess.Popen | None):
    pid = station.popen.pid
    cpu, threads, t = process_cpu_s(pid), thread_cpu_s(pid), time.monotonic()
    counts = stop_counting(perf, counters_path(station))
    switches = thread_switches(pid)
    status = httpx.get(f"{station.base}/api/status", timeout=10).json()
    host = probe_in_subprocess()
    warm = warm_speed() if counts else None
    return cpu, threads, switches, status, t, os.getloadavg()[0], host, counts, warm


# -- printing ----------------------------------------------------------------------------------


def switches_per_s(run: Run) -> tuple[float, float]:
    """The whole process's (voluntary, involuntary) context switches per second."""
    return (
        sum(v for v, _ in run.switches.values()) / run.seconds,
        sum(n for _, n in run.switches.values()) / run.seconds,
    )


def describe_counters(c: dict[str, float]) -> str:
    """Instructions a second (the work) and cycles per instruction (what the host's cold
    caches made of it), user and kernel."""
    parts = []
    for ring, name in (("u", "user"), ("k", "kernel")):
        insn, cycles = c.get(f"instructions:{ring}"), c.get(f"cycles:{ring}")
        if insn:
            cpi = f", {cycles / insn:.2f} cycles each" if cycles else ""
            parts.append(f"{name} {insn / 1e6:.0f} M instructions/s{cpi}")
    return "; ".join(parts)


def thread_counter_columns(c: dict[str, float]) -> str:
    """A thread's columns of the table with perf: user instructions a second (millions)
    and cycles per instruction; dashes for a thread perf did not count."""
    insn, cycles = c.get("instructions:u", 0.0), c.get("cycles:u", 0.0)
    if not insn:
        return f" {'-':>9} {'-':>8}"
    return f" {insn / 1e6:>9.1f} {cycles / insn:>8.2f}"


def warm_share(run: Run) -> float | None:
    """% of one core the run's user instructions would take at warm Python's speed."""
    insn = run.counters.get("instructions:u")
    return insn / run.warm_insn_per_s * 100 if insn and run.warm_insn_per_s else None


def summary_counters(c: dict[str, float]) -> str:
    """All instructions a second and cycles per instruction, user and kernel together."""
    insn = c.get("instructions:u", 0.0) + c.get("instructions:k", 0.0)
    cycles = c.get("cycles:u", 0.0) + c.get("cycles:k", 0.0)
    return f"M insn/s {insn / 1e6:4.0f}  cycles/insn {cycles / insn:4.2f}" if insn else ""


def report(run: Run) -> None:
    pct = run.cpu_s / run.seconds * 100
    print(
        f"\n## {run.label}: CPU {pct:.1f} % of one core, RSS {run.rss_mb:.0f} MB "
        f"({run.rss_anon_mb:.0f} MB of it anonymous; {run.rss_ready_mb:.0f} MB when ready), "
        f"ready in {run.ready_s:.2f} s ({run.ready_cpu_s:.2f} CPU s); "
        f"load {run.load[0]:.2f} -> {run.load[1]:.2f}"
    )
    print(
        f"   link {run.packets_per_s:.0f} packets/s; cameras "
        + ", ".join(f"{k} {v:.1f} fps" for k, v in run.fps.items())
        + "; telemetry msg/s per client "
        + ", ".join(f"{m:.1f}" for m in run.telemetry_msgs_per_s)
        + "; MJPEG fps per viewer "
        + ", ".join(f"{f:.1f}" for f in run.viewer_fps)
    )
    print(
        "   per component (% of one core): "
        + ", ".join(f"{c} {s / run.seconds * 100:.2f}" for c, s in run.components.items())
    )
    vol, invol = switches_per_s(run)
    print(
        f"   context switches/s: {vol:.0f} voluntary (about one wake-up each), {invol:.0f} "
        f"involuntary; host: a wake-up costs {run.host_wake_us[0]:.0f} / "
        f"{run.host_wake_us[1]:.0f} us of CPU before / after (host_wake_cost.py)"
    )
    if run.counters:
        print(f"   perf stat: {describe_counters(run.counters)}")
        share = warm_share(run)
        if share is not None and run.warm_insn_per_s is not None:
            print(
                f"   at warm Python's speed here ({run.warm_insn_per_s / 1e6:.0f} M instructions "
                f"per CPU second) the user instructions would take {share:.2f} % of one core"
            )
    # With perf, each thread's user instructions a second and the cycles each took: a
    # thread that works in batches runs them warm, one woken for each item cold.
    counted = " M insn/s cyc/insn" if run.thread_counters else ""
    print(
        f"   {'thread':<40} {'tid':>7} {'% core':>7} {'of it sys':>9} {'vol/s':>6} {'invol/s':>7}"
        + counted
    )
    for info, cpu in run.threads:
        if cpu > 0:
            sys_pct = run.thread_sys_s[info.tid] / run.seconds * 100
            v, n = run.switches.get(info.tid, (0, 0))
            print(
                f"   {info.name[:40]:<40} {info.tid:>7} {cpu / run.seconds * 100:>7.2f} "
                f"{sys_pct:>9.2f} {v / run.seconds:>6.0f} {n / run.seconds:>7.0f}"
                + (thread_counter_columns(run.thread_counters.get(info.tid, {})) if counted else "")
            )
    idle = [info.name for info, cpu in run.threads if cpu <= 0]
    if idle:
        print(f"   idle threads: {', '.join(idle)}")
    if run.top:
        print("   busiest functions (self time, share of py-spy samples):")
        for fn, share in run.top:
            print(f"   {share * 100:5.1f} %  {fn}")


def add_variant_option(
    ap: argparse.ArgumentParser, flag: str, names: tuple[str, str], help: str
) -> None:
    """An option naming the plain configuration, a variant of it, or both side by side."""
    ap.add_argument(flag, choices=(*names, "both"), default=names[0], help=help)


def variant_runs(choice: str, variant: str) -> tuple[bool, ...]:
    """Whether each run of an option's choice is the variant: one run, or both in turn."""
    return (False, True) if choice == "both" else (choice == variant,)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="measured window per run")
    ap.add_argument("--warmup", type=float, default=5.0, help="after start, before the window")
    ap.add_argument("--repeat", type=int, default=2, help="runs per configuration")
    ap.add_argument("--3d", dest="three_d", choices=("both", "on", "off"), default="both")
    ap.add_argument("--viewers", type=int, default=2, help="MJPEG viewers per camera")
    # The configuration is the default; fewer clients or no recording measure
    # what each part costs (the difference), not the budget.
    ap.add_argument("--telemetry-clients", type=int, default=2, help="telemetry WebSockets")
    ap.add_argument("--no-record", action="store_true", help="no recording")
    ap.add_argument(
        "--count-instructions",
        action="store_true",
        help="perf stat's instructions and cycles over the window (the work, whatever the "
        "host; perf's counting adds to the CPU figure under a VM: compare like with like)",
    )
    ap.add_argument(
        "--telemetry-ack",
        type=int,
        default=PAGE_ACK_WINDOW,
        metavar="N",
        help="telemetry clients as the pages run them: ?ack=N, an ack when N messages are "
        "unacknowledged (2, web/telemetry.js; 1: an ack per message; 0: clients that only "
        "read)",
    )
    ap.add_argument(
        "--no-telemetry-ack",
        dest="telemetry_ack",
        action="store_const",
        const=0,
        help="--telemetry-ack 0",
    )
    add_variant_option(
        ap,
        "--rates",
        ("default", "small-pi"),
        "the station's default message rates, a small Pi's (deploy/config.toml's "
        "commented lines: --baseline stations older than them refuse it), or both side by side",
    )
    add_variant_option(
        ap,
        "--autopilot-streams",
        ("requested", "px4-onboard"),
        "what the vehicle streams besides what the station asks for: nothing, or what "
        "PX4 sends in MAV_X_MODE Onboard (about 210 packets/s more), or both side by side",
    )
    ap.add_argument("--no-profile", action="store_true", help="no py-spy (no loop split)")
    ap.add_argument(
        "--no-visit",
        action="store_true",
        help="do not ask GET /api/viser (as the pilot page does): the 3D panels stay unstarted",
    )
    ap.add_argument("--profile-out", type=Path, help="keep py-spy's raw samples in this folder")
    ap.add_argument(
        "--profile-rate",
        type=int,
        default=100,
        help="py-spy samples a second (more: a finer profile, and py-spy's own cost in the "
        "figures)",
    )
    ap.add_argument(
        "--baseline",
        type=Path,
        dest="station_root",
        help="also run the station of this checkout (e.g. an older commit's `git archive`), "
        "alternating with this one, to compare side by side under the same load",
    )
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="fpv-bench-pi-"))
    make_frames(tmp / "front", ".jpg")
    make_frames(tmp / "bottom", ".jpg")
    print(
        f"# fpv-station Pi budget: UDP test vehicle, 2 USB MJPEG cameras 640x480 @ 30 fps "
        f"(passthrough), {'no recording' if args.no_record else 'recording'}, "
        f"{args.telemetry_clients} telemetry clients{f' (ack={args.telemetry_ack})' if args.telemetry_ack else ''}, "
        f"{args.viewers} viewers per camera; "
        f"{args.seconds:g} s windows after {args.warmup:g} s; machine {platform.machine()}, "
        f"{os.cpu_count()} cores, Python {platform.python_version()}; "
        f"py-spy {'yes' if py_spy() and not args.no_profile else 'no'}"
    )
    for root in {ROOT, args.station_root or ROOT}:
        prepare_checkout(root)
    configs = {"both": (True, False), "on": (True,), "off": (False,)}[args.three_d]
    roots = (
        [(None, "")] if args.station_root is None else [(args.station_root, "base "), (None, "")]
    )
    rate_sets = variant_runs(args.rates, "small-pi")
    stream_sets = variant_runs(args.autopilot_streams, "px4-onboard")
    runs = []
    for i in range(args.repeat):
        for with_3d in configs:
            for small_pi in rate_sets:
                for px4_onboard in stream_sets:
                    for root, tag in roots:
                        args_i = argparse.Namespace(**{**vars(args), "station_root": root})
                        rates = " small-pi" if small_pi else ""
                        streams = " px4-onboard" if px4_onboard else ""
                        label = f"{tag}3D {'on' if with_3d else 'off'}{rates}{streams} #{i + 1}"
                        run = one_run(args_i, tmp, with_3d, label, small_pi, px4_onboard)
                        report(run)
                        runs.append(run)
    print("\n# summary")
    for run in runs:
        print(
            f"{run.label:<32} CPU {run.cpu_s / run.seconds * 100:5.1f} %  RSS {run.rss_mb:5.0f} MB"
            f" ({run.rss_ready_mb:3.0f} at ready, {run.rss_anon_mb:3.0f} anon)"
            f"  ready {run.ready_s:5.2f} s ({run.ready_cpu_s:4.2f} CPU s)"
            f"  load {run.load[0]:.2f}->{run.load[1]:.2f}"
            f"  switches/s {sum(switches_per_s(run)):4.0f}"
            f"  host wake {run.host_wake_us[0]:3.0f}/{run.host_wake_us[1]:3.0f} us"
            + (f"  {summary_counters(run.counters)}" if run.counters else "")
            + (f"  warm {share:.2f} %" if (share := warm_share(run)) is not None else "")
        )
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
