"""Analysis speed: load + paper's metrics (+ figures) for 1, 10 and 60 min sessions at 50 Hz.

    python benchmarks/analysis.py [--minutes 1 10 60] [--rate-hz 50] [--repeat 3]

Sessions are synthetic A-to-B flights written in the recorder's own telemetry.csv format
(every VehicleState column plus the camera columns, GPS at 10 Hz held between updates),
and as a bare .tlog. Prints the best of `--repeat` runs for each stage.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import TypeVar

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fpv_station.analysis.report import analyze_tracks  # noqa: E402
from fpv_station.analysis.track import load_track  # noqa: E402
from tests import synthetic as syn  # noqa: E402

PLOT_KINDS = ("trajectory3d", "birdseye", "history")


T = TypeVar("T")


def best(fn: Callable[[], T], repeat: int) -> tuple[float, T]:
    """Best wall time of `repeat` runs (the machine is shared), and the result."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def best_cpu(fn, repeat: int) -> float:
    """Best CPU time of this process: what the work costs, whatever else runs."""
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, nargs="+", default=[1, 10, 60])
    ap.add_argument("--rate-hz", type=float, default=50.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print(
        f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    )
    print(f"load average: {os.getloadavg()[0]:.1f}")
    print(
        "| session | rows | CSV MB | load CSV (s) | metrics (s) | load+metrics (s) "
        "| load+metrics CPU (s) | 3 figures (s) | load tlog (s) |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    with tempfile.TemporaryDirectory() as tmp:
        for minutes in args.minutes:
            seconds = minutes * 60
            # A-to-B long enough to fill the session at 1.2 m/s (climb and landing add ~12 s).
            flight = syn.a_to_b_flight(length_m=1.2 * (seconds - 12), dt=1 / args.rate_hz)
            folder = syn.write_session(flight, Path(tmp) / f"s{minutes:g}")
            tlog = syn.write_tlog(flight, Path(tmp) / f"s{minutes:g}.tlog")
            csv_mb = (folder / "telemetry.csv").stat().st_size / 1e6
            t_load, track = best(partial(load_track, folder), args.repeat)
            t_metrics, an = best(partial(analyze_tracks, [track], "a-to-b"), args.repeat)

            def both(folder: Path = folder) -> object:
                return analyze_tracks([load_track(folder)], "a-to-b")

            t_both, _ = best(both, args.repeat)
            cpu_both = best_cpu(both, args.repeat)
            t_plots, _ = best(partial(lambda an: [an.plot(k) for k in PLOT_KINDS], an), 1)
            t_tlog, _ = best(partial(load_track, tlog), 1)
            print(
                f"| {minutes:g} min | {flight.t_s.size} | {csv_mb:.1f} | {t_load:.3f} | "
                f"{t_metrics:.4f} | {t_both:.3f} | {cpu_both:.3f} | {t_plots:.2f} | {t_tlog:.2f} |"
            )


if __name__ == "__main__":
    main()
