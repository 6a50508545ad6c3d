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
import subprocess
import sys
import time
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--wakes", type=int, default=100)
    ap.add_argument("--sleep-ms", type=float, default=5.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--quiet", action="store_true", help="print the per-wake figure only")
    args = ap.parse_args()
    if args.quiet:
        print(f"{wake_cost_us(args.wakes, args.sleep_ms / 1e3):.1f}")
        return
    print(f"# warm step: {warm_step_us():.1f} us of CPU")
    for _ in range(args.repeat):
        cost = wake_cost_us(args.wakes, args.sleep_ms / 1e3)
        print(
            f"{time.strftime('%H:%M:%S')} step after a {args.sleep_ms:g} ms sleep: {cost:.1f} us of CPU"
        )


if __name__ == "__main__":
    main()
