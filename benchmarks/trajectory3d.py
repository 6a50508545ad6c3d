"""The 3D panel's cost per update over a long flight, and the replay endpoint's build time.

    python benchmarks/trajectory3d.py [--minutes 30] [--hz 10]

Feeds a flight (figure 8 with GPS noise and a 2 s dropout every 5 minutes) into the live
scene one state per step, as the update loop does, on a real viser server, twice: with one
viewer connected (tests.helpers.viser_viewer: the scene is drawn) and with none (only the
trail is kept). Prints per 5-minute block: CPU time of the step's thread (p50/p99),
messages and array bytes queued for viewers per step, and the scene's trail handles. A
flat cost means the last block matches the first. Then times `build_trajectory`.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fpv_station.companion.latest import Latest  # noqa: E402
from fpv_station.companion.vehicle_state import Attitude, GlobalPosition, GpsRaw, VehicleState  # noqa: E402
from fpv_station.core.geodesy import enu_to_geodetic  # noqa: E402
from fpv_station.core.scene import load_scene  # noqa: E402
from fpv_station.server.settings import ViserSettings  # noqa: E402
from fpv_station.server.trajectory3d.replay import build_trajectory  # noqa: E402
from fpv_station.server.trajectory3d.service import Trajectory3D  # noqa: E402
from tests.helpers import viser_viewer, wait_until  # noqa: E402


def array_bytes(obj) -> int:
    if isinstance(obj, np.ndarray):
        return obj.nbytes
    if dataclasses.is_dataclass(obj):
        return sum(array_bytes(getattr(obj, f.name)) for f in dataclasses.fields(obj))
    if isinstance(obj, dict):
        return sum(array_bytes(v) for v in obj.values())
    return 0


def fly(args: argparse.Namespace, field, geo: np.ndarray, t: np.ndarray, watched: bool) -> None:
    n = len(t)
    svc = Trajectory3D(ViserSettings(port=0), Latest(), host="127.0.0.1", field=field)
    svc.start()
    with contextlib.ExitStack() as stack:
        if watched:
            stack.enter_context(viser_viewer(svc.port))
            assert wait_until(svc.watched)
        assert svc.server is not None and svc.scene is not None
        buffer = svc.server._websock_server.get_message_buffer()
        cpu, msgs, nbytes = np.zeros(n), np.zeros(n), np.zeros(n)
        for i in range(n):
            lat, lon, alt = (float(v) for v in geo[i])
            ti = float(t[i])
            fix = 1 if (i % int(300 * args.hz)) < int(2 * args.hz) else 3
            state = VehicleState(
                gps=GpsRaw(t_mono=ti, fix_type=fix, lat_deg=lat, lon_deg=lon, alt_m=alt),
                global_position=GlobalPosition(
                    t_mono=ti, lat_deg=lat, lon_deg=lon, alt_m=alt, vx_mps=1.2, vy_mps=0.3
                ),
                attitude=Attitude(t_mono=ti, roll_rad=0.05, pitch_rad=-0.1, yaw_rad=ti / 20),
            )
            first = buffer.message_counter
            c0 = time.thread_time()
            svc.step(state)
            cpu[i] = time.thread_time() - c0
            ids = range(first, buffer.message_counter)
            msgs[i] = len(ids)
            nbytes[i] = sum(array_bytes(buffer.message_from_id.get(m)) for m in ids)
        chunks = len(svc.scene.chunk_handles)
    svc.stop()

    block = int(300 * args.hz)
    print(
        f"live scene, {'one viewer' if watched else 'no viewer'}: {args.minutes:.0f} min at "
        f"{args.hz:.0f} Hz ({n} steps), chunk of {svc.settings.chunk_segments} segments"
    )
    print("minutes   cpu/step p50   p99      msgs/step  bytes/step")
    for b0 in range(0, n, block):
        sl = slice(b0, min(n, b0 + block))
        print(
            f"{b0 / args.hz / 60:5.0f}-{min(n, b0 + block) / args.hz / 60:<4.0f}"
            f" {np.median(cpu[sl]) * 1e3:8.3f} ms {np.percentile(cpu[sl], 99) * 1e3:6.3f} ms"
            f" {msgs[sl].mean():9.2f} {nbytes[sl].mean():11.0f}"
        )
    print(
        f"trail handles at the end: {chunks}; CPU at 15 Hz: "
        f"{np.mean(cpu) * 15 * 100:.2f}% of one core"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--hz", type=float, default=10.0)
    args = ap.parse_args()
    field = load_scene()
    origin = field.home_llh
    n = int(args.minutes * 60 * args.hz)
    t = np.arange(n) / args.hz
    rng = np.random.default_rng(0)
    enu = np.column_stack([12 * np.sin(t / 20), 6 * np.sin(t / 10), 3 + rng.normal(0, 0.3, n)])
    enu[:, :2] += rng.normal(0, 0.5, (n, 2))  # M8N-like horizontal noise
    geo = enu_to_geodetic(enu, *origin)

    for watched in (True, False):
        fly(args, field, geo, t, watched)

    c0 = time.process_time()
    for _ in range(5):
        build_trajectory("bench", t, geo[:, 0], geo[:, 1], geo[:, 2], align="farthest")
    print(
        f"replay: build_trajectory for {n} fixes: {(time.process_time() - c0) / 5 * 1e3:.1f} ms CPU"
    )


if __name__ == "__main__":
    main()
