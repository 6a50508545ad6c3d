"""Shutdown under load: SIGTERM to `fpv-station serve --source sim` (3D panels on,
recording) with telemetry clients, MJPEG viewers and clients that stopped reading
connected; how long until the process has exited (target: within 5 s).

    python benchmarks/shutdown.py [--runs 3] [--telemetry 100] [--viewers 20] [--stalled 5]

Prints each run's seconds from SIGTERM to exit, tracebacks in the server's output and
the session's final status, then the median and the worst. Figures go in
docs/PERFORMANCE.md with the load average.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.shutdown_load import sigterm_under_load  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--telemetry", type=int, default=100)
    ap.add_argument("--viewers", type=int, default=20)
    ap.add_argument("--stalled", type=int, default=5)
    ap.add_argument("--hold", type=float, default=5.0, help="seconds of load before SIGTERM")
    args = ap.parse_args()
    print(
        f"# shutdown under load: {args.telemetry} telemetry clients, {args.viewers} MJPEG "
        f"viewers, {args.stalled} stalled, recording on the twin, 3D panels on; machine "
        f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    )
    times = []
    for i in range(args.runs):
        with tempfile.TemporaryDirectory(prefix="fpv-bench-shutdown-") as tmp:
            run = sigterm_under_load(
                Path(tmp), args.telemetry, args.viewers, args.stalled, hold_s=args.hold
            )
        times.append(run.exit_s)
        print(
            f"run {i + 1}: SIGTERM to exit {run.exit_s:.2f} s, exit code {run.returncode}, "
            f"tracebacks {run.output.count('Traceback')}, session {run.session['status']} "
            f"({run.session['stop_reason']}), load {os.getloadavg()[0]:.2f}",
            flush=True,
        )
    print(f"SIGTERM to exit: median {statistics.median(times):.2f} s, worst {max(times):.2f} s")


if __name__ == "__main__":
    main()
