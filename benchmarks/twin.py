"""Digital twin benchmark: physics throughput (for learning) and the CPU cost of flying
with both cameras rendered at 30 fps (for the station).

    python benchmarks/twin.py [--seconds 10]

Prints one line per figure. CPU is process time (user + system) of this process, so
other load on the machine does not count; wall rates do depend on it.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402

from fpv_station.twin.pilot import Leg, Pilot, fly  # noqa: E402
from fpv_station.twin.render import Renderer  # noqa: E402
from fpv_station.twin.sim import Sim  # noqa: E402


def hovering_sim(n: int = 1) -> Sim:
    sim = Sim(n=n)
    sim.run_for(2.5)
    for i in range(n):
        sim.arm(i=i)
        sim.set_sticks(0.0, 0.0, 0.0, 0.9, i=i)
    sim.run_for(1.5)
    sim.sticks[:] = [0.3, 0.4, 0.0, 0.5]  # moving, so every branch of the controller works
    return sim


def physics_rate(n: int, steps: int) -> tuple[float, float]:
    sim = hovering_sim(n)
    t0, c0 = time.perf_counter(), time.process_time()
    sim.step(steps)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return steps * n / wall, steps * n / cpu


def dynamics_rate(steps: int) -> float:
    sim = hovering_sim(1)
    dyn, s, u = sim.dynamics, sim.state, sim.throttle.copy()
    c0 = time.process_time()
    for _ in range(steps):
        dyn.step(s, u)
    return steps / (time.process_time() - c0)


def vector_env_rate(num_envs: int, steps: int) -> tuple[float, float]:
    """Gymnasium vector env: env steps/s and the physics vehicle-steps/s behind them."""
    from fpv_station.twin.gym_vector import TwinVectorEnv

    env = TwinVectorEnv(num_envs=num_envs)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-0.3, 0.3, (steps, num_envs, 4))
    c0 = time.process_time()
    for a in actions:
        env.step(a)
    cpu = time.process_time() - c0
    per_step = int(round(1.0 / (env.control_hz * env.sim.dt_s)))
    return steps * num_envs / cpu, steps * num_envs * per_step / cpu


def flight_with_cameras(seconds: float, fpv_noise: bool) -> tuple[float, float, float]:
    """CPU seconds per simulated second: physics + front + bottom at 30 fps each."""
    sim = Sim()
    sim.run_for(2.5)
    fly(sim, Pilot([Leg("arm"), Leg("climb", alt_m=3.0)]), timeout_s=20)
    sim.set_sticks(0.2, 0.5, 0.1, 0.5)
    renderer = Renderer(sim.scene, fpv_noise=fpv_noise)
    per_frame = int(round(1 / 30 / sim.dt_s))
    frames = int(seconds * 30)
    render_cpu = 0.0
    c0 = time.process_time()
    for _ in range(frames):
        sim.step(per_frame)
        r0 = time.process_time()
        pose = sim.pose()
        renderer.render("front", pose)
        renderer.render("bottom", pose)
        render_cpu += time.process_time() - r0
    cpu = time.process_time() - c0
    sim_s = frames * per_frame * sim.dt_s
    return cpu / sim_s, render_cpu / (2 * frames) * 1000, sim_s


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="simulated seconds with cameras")
    args = ap.parse_args()
    print(
        f"machine: {platform.machine()}, {os.cpu_count()} cores, {platform.python_version()}, "
        f"numpy {np.__version__}"
    )
    wall, cpu = physics_rate(1, 5000)
    print(
        f"physics, 1 vehicle (control + sensors + dynamics): {cpu:,.0f} steps/s per CPU "
        f"second ({wall:,.0f} wall)"
    )
    print(f"dynamics only, 1 vehicle: {dynamics_rate(5000):,.0f} steps/s per CPU second")
    for n in (64, 512):
        wall, cpu = physics_rate(n, 1000)
        print(
            f"physics, batch of {n} vehicles: {cpu:,.0f} vehicle-steps/s per CPU second "
            f"({wall:,.0f} wall)"
        )
    env_rate, phys_rate = vector_env_rate(64, 40)
    print(
        f"gymnasium TwinVectorEnv, 64 envs at 10 Hz control: {env_rate:,.0f} env-steps/s "
        f"per CPU second ({phys_rate:,.0f} physics vehicle-steps/s)"
    )
    for noise in (False, True):
        cost, ms, sim_s = flight_with_cameras(args.seconds, noise)
        print(
            f"flight with both cameras at 30 fps{' + analog noise' if noise else ''}: "
            f"{cost:.2f} CPU s per simulated s ({100 * cost:.0f} % of one core; "
            f"{ms:.1f} ms per frame; {sim_s:.0f} s flown)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
