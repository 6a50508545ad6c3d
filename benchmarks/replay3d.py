"""The 3D replay panel's costs: loading a long session into the scene, and one time step.

    python benchmarks/replay3d.py [--minutes 30] [--hz 10] [--steps 2000]

Builds a figure-8 flight as `build_trajectory` does for a recorded session, loads it (and
itself as the overlay) into a real replay viser server with no viewer connected, and
prints the load time, the scene handles, and CPU time per `set_time` (p50/p99), the work
behind each PUT /api/replay3d/time.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fpv_station.core.geodesy import enu_to_geodetic  # noqa: E402
from fpv_station.core.scene import load_scene  # noqa: E402
from fpv_station.server.settings import ViserSettings  # noqa: E402
from fpv_station.server.trajectory3d.replay import build_trajectory  # noqa: E402
from fpv_station.server.trajectory3d.replay_scene import Replay3D  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--hz", type=float, default=10.0)
    ap.add_argument("--steps", type=int, default=2000)
    args = ap.parse_args()
    f = load_scene()
    t = np.arange(0, args.minutes * 60, 1 / args.hz)
    enu = np.column_stack([12 * np.sin(t / 8), 6 * np.sin(t / 4), 3 + np.sin(t / 30)])
    lat, lon, alt = enu_to_geodetic(enu, *f.home_llh).T
    reply = build_trajectory("bench", t, lat, lon, alt, speed_mps=np.full(t.size, 1.5))
    svc = Replay3D(ViserSettings(port=0), host="127.0.0.1", field=f)
    svc.start()
    try:
        c0, w0 = time.process_time(), time.perf_counter()
        svc.load(reply, reply)
        assert svc.scene is not None
        print(
            f"load: {t.size} fixes + overlay: {1e3 * (time.process_time() - c0):.0f} ms CPU, "
            f"{1e3 * (time.perf_counter() - w0):.0f} ms wall; "
            f"{len(svc.scene.chunk_handles)} path handles"
        )
        rng = np.random.default_rng(0)
        cpu = []
        for ts in rng.uniform(0, t[-1], args.steps):
            c = time.process_time()
            svc.set_time(float(ts))
            cpu.append(time.process_time() - c)
        ms = 1e3 * np.asarray(cpu)
        print(
            f"set_time: p50 {np.percentile(ms, 50):.2f} ms, p99 {np.percentile(ms, 99):.2f} ms "
            f"CPU over {args.steps} random instants"
        )
    finally:
        svc.stop()


if __name__ == "__main__":
    main()
