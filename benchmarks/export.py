"""Export throughput and peak memory: LeRobot, Minari and MCAP on 10 minutes of twin flight,
and LeRobot's throughput with 1 and 2 worker processes (and on a local Ray instance).

    python benchmarks/export.py [--minutes 10] [--camera-fps 15] [--keep DIR]
                                [--workers 1,2] [--ray] [--no-formats]

The flights are `fpv-station demos` sessions (the scripted pilot, real MAVLink, both
cameras at 640x480): one long session of `--minutes` (a hover held that long), the same
time as ten short sessions (ten episodes), and a session of a fifth of the length, to
show that memory does not grow with session length. Each export runs in its own process
(resident memory sampled every 20 ms; the RSS after the imports, before the export,
printed apart). Prints flight seconds per
export second (x real time), episodes and camera frames per second, and peak memory.
Then the ten sessions exported to LeRobot by `--workers` processes each (`fpv-station
export --workers N`; the dataset is the same for any N) and, with `--ray`, as tasks on a
new local Ray instance (`--ray local`, the `export-ray` extra), its start-up included:
recordings and flight seconds per export second, and the CPU seconds of the process
that assembles the dataset and of its worker processes (Ray's own processes are not
counted): the assembling process's share bounds the speed-up more workers can give, and
CPU seconds hold on a loaded machine where wall times do not.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
PYTHONPATH = os.environ.get("PYTHONPATH", "")  # the exports run this tree, and what else is set

from fpv_station.learn.demos import DemoConfig, fly_demo  # noqa: E402

CHILD = """
import json, sys, threading, time
from pathlib import Path
import psutil
from fpv_station.learn.export import ExportOptions, export_recordings
import fpv_station.learn.lerobot, fpv_station.learn.minari_export, fpv_station.learn.mcap_export, minari, foxglove, av  # noqa
proc = psutil.Process()
base = proc.memory_info().rss
peak = [base]
done = threading.Event()
def sample():  # the process's resident memory every 20 ms while it exports
    while not done.wait(0.02):
        peak[0] = max(peak[0], proc.memory_info().rss)
threading.Thread(target=sample, daemon=True).start()
fmt, workers, ray, out, *paths = sys.argv[1:]
opts = ExportOptions(task_id=1, workers=int(workers), ray_address=ray or None)
t0 = time.perf_counter()
s = export_recordings([Path(p) for p in paths], fmt, Path(out), opts)
dt = time.perf_counter() - t0
done.set()
peak[0] = max(peak[0], proc.memory_info().rss)
import resource
me, kids = (resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN))
print(json.dumps({"s": dt, "episodes": s.episodes, "frames": s.frames,
                  "camera_frames": s.camera_frames, "base_kb": base / 1024, "peak_kb": peak[0] / 1024,
                  "cpu_self_s": me.ru_utime + me.ru_stime, "cpu_workers_s": kids.ru_utime + kids.ru_stime}))
"""


def flight_s(folder: Path) -> float:
    return float(json.loads((folder / "session.json").read_text())["duration_s"])


def sessions(root: Path, minutes: float, camera_fps: float, names) -> dict[str, list[Path]]:
    """The sets named (`long`, `short`, `ten`), flown once and kept under `root`."""
    marker = root / "sessions.json"
    have = json.loads(marker.read_text()) if marker.is_file() else {}
    cfg = DemoConfig(task_id=1, cameras=True, camera_fps=camera_fps, timeout_s=minutes * 60 + 120)
    climb_land_s = 18.0  # the hover task without its hold: climb to 4 m, descend, disarm
    plans = {  # seed, hover hold (s), count
        "long": (1, minutes * 60 - climb_land_s, 1),
        "short": (2, minutes * 12 - climb_land_s, 1),
        "ten": (10, minutes * 6 - climb_land_s, 10),
    }
    t0 = time.perf_counter()
    for name in names:
        if name in have:
            continue
        seed, hold_s, count = plans[name]
        if hold_s <= 0:
            raise SystemExit(f"--minutes {minutes} is too short for the '{name}' sessions")
        have[name] = [
            str(fly_demo(root / name, seed + k, DemoConfig(**{**cfg.__dict__, "hold_s": hold_s})))
            for k in range(count)
        ]
        marker.write_text(json.dumps(have))
    print(f"flew the sessions in {time.perf_counter() - t0:.0f} s", flush=True)
    return {k: [Path(p) for p in v] for k, v in have.items()}


def run_child(fmt: str, paths: list[Path], workers: int = 1, ray: str = "") -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-out-") as out:
        r = subprocess.run(
            [sys.executable, "-c", CHILD, fmt, str(workers), ray, str(Path(out) / fmt)]
            + [str(p) for p in paths],
            capture_output=True,
            text=True,
            check=True,
            env={
                **os.environ,
                "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), PYTHONPATH])),
            },
        )
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--camera-fps", type=float, default=15.0)
    ap.add_argument("--keep", type=Path, help="folder for the flown sessions (reused if there)")
    ap.add_argument("--workers", default="1,2", help="worker counts to compare (LeRobot)")
    ap.add_argument("--ray", action="store_true", help="also on a local Ray instance")
    ap.add_argument("--no-formats", action="store_true", help="only the workers' table")
    ap.add_argument("--repeat", type=int, default=1, help="rounds of the workers' table")
    args = ap.parse_args()
    print(
        f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    )
    root = args.keep or Path(tempfile.mkdtemp(prefix="bench-export-"))
    root.mkdir(parents=True, exist_ok=True)
    names = ("ten",) if args.no_formats else ("long", "ten", "short")
    sets = sessions(root, args.minutes, args.camera_fps, names)
    print(f"load average before exports: {os.getloadavg()[0]:.2f}")
    if not args.no_formats:
        formats_table(sets)
    paths = sets["ten"]
    flown = sum(flight_s(p) for p in paths)
    print(f"\nLeRobot, {len(paths)} sessions, {flown:.0f} s of flight")
    print(
        "| engine | export (s) | x real time | recordings/s | camera frames/s "
        "| CPU s, assembling process | CPU s, worker processes | load before |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    engines = [(f"{n} worker(s)", int(n), "") for n in args.workers.split(",")]
    if args.ray:
        engines.append(("Ray (local instance)", 1, "local"))
    for _ in range(args.repeat):
        for name, workers, ray in engines:
            load = os.getloadavg()[0]
            m = run_child("lerobot", paths, workers, ray)
            print(
                f"| {name} | {m['s']:.1f} | {flown / m['s']:.1f} | {len(paths) / m['s']:.2f} | "
                f"{m['camera_frames'] / m['s']:.0f} | {m['cpu_self_s']:.1f} | "
                f"{m['cpu_workers_s']:.1f} | {load:.1f} |",
                flush=True,
            )
    print(f"load average after: {os.getloadavg()[0]:.2f}")


def formats_table(sets: dict[str, list[Path]]) -> None:
    print(
        "| sessions | flight (s) | format | export (s) | x real time | episodes/s | camera frames/s | peak RSS (MB) | RSS before export (MB) |"
    )
    print("| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for name in ("long", "ten", "short"):
        paths = sets[name]
        flown = sum(flight_s(p) for p in paths)
        for fmt in ("lerobot", "minari", "mcap"):
            m = run_child(fmt, paths)
            print(
                f"| {name} ({len(paths)}) | {flown:.0f} | {fmt} | {m['s']:.1f} | {flown / m['s']:.1f} | "
                f"{m['episodes'] / m['s']:.2f} | {m['camera_frames'] / m['s']:.0f} | "
                f"{m['peak_kb'] / 1024:.0f} | {m['base_kb'] / 1024:.0f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
