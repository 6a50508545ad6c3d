"""What one wake-up of a sleeping thread costs on this host, in CPU microseconds.

    python benchmarks/host_wake_cost.py [--wakes 100] [--sleep-ms 5] [--repeat 5]

A thread sleeps `--sleep-ms`, wakes, runs the same few microseconds of Python, and sleeps
again; the figure is its CPU time (`time.thread_time`) per wake-up. In a warm loop the
step alone takes a few microseconds; after a sleep it takes far more: the caches went cold
while the thread slept, and under a hypervisor the idle vCPU has to be woken too.

A station is mostly such wake-ups (hundreds a second: datagrams, camera frames, telemetry
ticks, acknowledgements), so its CPU figures move with this one: pi_budget.py runs this
probe before and after each window and prints it next to the station's figures, so that a
reader can tell a slower host from a slower station (docs/PERFORMANCE.md).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path


def _step() -> int:
    total = 0
    for i in range(300):
        total += i * i % 7
    return total


def warm_step_us(n: int = 2000) -> float:
    """The step's CPU time in a warm loop."""
    t0 = time.thread_time()
    for _ in range(n):
        _step()
    return (time.thread_time() - t0) / n * 1e6


def wake_cost_us(wakes: int = 100, sleep_s: float = 0.005) -> float:
    """CPU microseconds per wake-up of a thread that sleeps `sleep_s` between steps."""
    t0 = time.thread_time()
    for _ in range(wakes):
        time.sleep(sleep_s)
        _step()
    return (time.thread_time() - t0) / wakes * 1e6


def probe_in_subprocess(wakes: int = 100, sleep_s: float = 0.005) -> float:
    """`wake_cost_us` in a fresh interpreter: a benchmark's own busy threads must not hold
    the probe's GIL."""
    out = subprocess.run(
        [
            sys.executable,
            str(Path(__file__)),
            "--wakes",
            str(wakes),
            "--sleep-ms",
            str(sleep_s * 1e3),
            "--repeat",
            "1",
            "--quiet",
        ],
        capture_output=True,
        text=True,
        check=True,
        timeout=30,
    )
    return float(out.stdout.split()[0])


def busy(seconds: float) -> None:
    """The step in a warm loop for `seconds`: what perf stat times for `warm_speed`."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        _step()


def warm_speed(seconds: float = 2.0) -> float | None:
    """User-space instructions warm Python runs here per second of CPU (perf stat over
    `busy` in a fresh interpreter); None without perf or its counters.

    A process's user instructions a second over this figure is the share of one core its
    work would take at warm speed; the rest of its user time is the cost of waking
    (docs/PERFORMANCE.md, "Where the Pi configuration's cycles go")."""
    perf = shutil.which("perf")
    if perf is None:
        return None
    command = [sys.executable, str(Path(__file__)), "--busy", str(seconds)]
    out = subprocess.run(
        [perf, "stat", "-x,", "-e", "instructions:u,task-clock", "--", *command],
        capture_output=True,
        text=True,
        timeout=30,
    )
    counts = perf_counts(out.stderr)
    instructions, cpu_ms = counts.get("instructions:u"), counts.get("task-clock")
    return instructions / (cpu_ms / 1e3) if instructions and cpu_ms else None


def perf_counts(text: str) -> dict[str, float]:
    """Event -> count in `perf stat -x,` output (value,unit,event,...); what perf could
    not count ("<not supported>", "<not counted>") is left out."""
    return {event: value for _, event, value in _perf_lines(text, per_thread=False)}


def perf_counts_per_thread(text: str) -> dict[int, dict[str, float]]:
    """Thread id -> event -> count in `perf stat --per-thread -x,` output, whose lines
    start with the thread's `comm-tid` (python-28961,value,unit,event,...)."""
    counts: dict[int, dict[str, float]] = {}
    for tid, event, value in _perf_lines(text, per_thread=True):
        counts.setdefault(tid, {})[event] = value
    return counts


def _perf_lines(text: str, per_thread: bool) -> Iterator[tuple[int, str, float]]:
    """(thread id, or 0 without --per-thread; event; count) of each counted line."""
    for line in text.splitlines():
        fields = line.split(",")
        tid = "0"
        if per_thread:
            tid = fields.pop(0).rpartition("-")[2]
        value, _, event = (fields + ["", "", ""])[:3]
        try:
            yield int(tid), event, float(value)
        except ValueError:  # "<not counted>" and the like, or a comment line
            continue


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--wakes", type=int, default=100)
    ap.add_argument("--sleep-ms", type=float, default=5.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--quiet", action="store_true", help="print the per-wake figure only")
    ap.add_argument("--busy", type=float, help="only run the step warm for this many seconds")
    args = ap.parse_args()
    if args.busy is not None:
        busy(args.busy)
        return
    if args.quiet:
        print(f"{wake_cost_us(args.wakes, args.sleep_ms / 1e3):.1f}")
        return
    print(f"# warm step: {warm_step_us():.1f} us of CPU")
    speed = warm_speed()
    if speed is not None:
        print(f"# warm Python here: {speed / 1e6:.0f} M instructions per CPU second (perf stat)")
    for _ in range(args.repeat):
        cost = wake_cost_us(args.wakes, args.sleep_ms / 1e3)
        print(
            f"{time.strftime('%H:%M:%S')} step after a {args.sleep_ms:g} ms sleep: {cost:.1f} us of CPU"
        )


if __name__ == "__main__":
    main()
