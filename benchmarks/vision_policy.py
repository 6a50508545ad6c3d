"""The vision policy's benchmark of docs/LEARNING.md: task 1 flown from the bottom camera
and the attitude, beside the state-based behaviour clone.

    python benchmarks/vision_policy.py [--episodes 10] [--demos 10] [--conditions calm,wind]
                                       [--jobs 2] [--write-docs]

Per condition (benchmarks/learning.py's: calm, and wind with a random start), the
documented commands, in process: `fpv-station demos --cameras bottom --camera-fps 10`
flies `--demos` demonstrations (seeds 0, 1, ...), `fpv-station export --cameras bottom
--image-size 160x120` makes one LeRobot dataset of them, `fpv-station learn vision` and
`fpv-station learn bc` train both policies on it, and `learn eval`'s rows fly
`--episodes` episodes (one batch, seed 1000): the vision policy, the behaviour clone, the
scripted pilot, the open-loop replay of the demonstrations' sticks, random sticks, and
the demonstrations. Prints the Markdown tables, the vision policy against the clone, the
replay and random (Newcombe's interval of the success difference), the machine, its load
and the time; `--write-docs` puts them into docs/LEARNING.md between its markers.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.learning import CONDITIONS, machine, write_docs  # noqa: E402

TASK = 1
SEED = 1000
BEGIN = "<!-- benchmarks/vision_policy.py: begin -->"
END = "<!-- benchmarks/vision_policy.py: end -->"


def unit(condition: str, demos: int, episodes: int) -> tuple[str, str, float]:
    """One condition: demos, export, both policies, evaluation; (condition, Markdown, s)."""
    from fpv_station.learn import evaluate as ev
    from fpv_station.learn.bc import BcPolicy
    from fpv_station.learn.cli import add_air_arguments, air_options
    from fpv_station.learn.vision import VisionPolicy
    from fpv_station.server.cli import main as cli

    t0 = time.perf_counter()
    air = CONDITIONS[condition]
    with tempfile.TemporaryDirectory(prefix=f"vision-{condition}-") as tmp_name:
        tmp = Path(tmp_name)
        quiet = io.StringIO()
        with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
            argv = ["demos", "--task", str(TASK), "--count", str(demos), "--seed", "0"]
            argv += ["--cameras", "bottom", "--camera-fps", "10", "--out", str(tmp / "demos")]
            if cli([*argv, *air]) != 0:
                raise RuntimeError(f"demos failed: {quiet.getvalue()}")
            sessions = sorted(str(p) for p in (tmp / "demos").iterdir() if p.is_dir())
            argv = ["export", *sessions, "--format", "lerobot", "--out", str(tmp / "ds")]
            argv += ["--cameras", "bottom", "--image-size", "160x120", "--no-progress"]
            if cli(argv) != 0:
                raise RuntimeError(f"export failed: {quiet.getvalue()}")
            for kind, name in (("vision", "vision.npz"), ("bc", "bc.npz")):
                if cli(["learn", kind, str(tmp / "ds"), "--out", str(tmp / name)]) != 0:
                    raise RuntimeError(f"learn {kind} failed: {quiet.getvalue()}")
        vision = VisionPolicy.load(tmp / "vision.npz")
        bc = BcPolicy.load(tmp / "bc.npz")
        parser = argparse.ArgumentParser()
        add_air_arguments(parser)
        options = air_options(parser.parse_args(air))
        rows = ev.benchmark(vision, TASK, episodes, SEED, options, [Path(s) for s in sessions])
        clone = ev.evaluate(
            "behaviour cloning", lambda s: ev.policy_act(bc), TASK, episodes, SEED, options
        )
    rows.insert(1, clone)
    by_name = {r.name: r for r in rows}
    lines = [
        f"Task {TASK} ({ev.TASK_NAMES[TASK]}), {condition}: {demos} demonstrations "
        f"({len(vision.inputs)} frames, bottom camera 160x120), {episodes} episodes per "
        f"flown row, batch seed {SEED}.",
        "",
        ev.table(rows, TASK),
        "",
        *(
            f"- {ev.compare(rows[0], by_name[o])}"
            for o in ("behaviour cloning", "open-loop replay", "random")
            if o in by_name
        ),
    ]
    return condition, "\n".join(lines), time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--episodes", type=int, default=10, help="episodes per flown row")
    ap.add_argument("--demos", type=int, default=10, help="demonstrations")
    ap.add_argument("--conditions", default="calm,wind", help="of: " + ", ".join(CONDITIONS))
    ap.add_argument("--jobs", type=int, default=2, help="processes")
    ap.add_argument("--write-docs", action="store_true", help="update docs/LEARNING.md")
    args = ap.parse_args()
    conditions = args.conditions.split(",")
    start_machine, t0 = machine(), time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = [pool.submit(unit, c, args.demos, args.episodes) for c in conditions]
        results = []
        for f in futures:
            results.append(f.result())
            c, md, s = results[-1]
            print(f"[{c}: {s:.0f} s, {machine()}]\n{md}\n", file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    parts = [
        f"Generated by `python benchmarks/vision_policy.py --episodes {args.episodes} "
        f"--demos {args.demos} --conditions {args.conditions} --jobs {args.jobs}` on "
        f"{time.strftime('%Y-%m-%d', time.gmtime())} in {wall / 60:.0f} min on "
        f"{start_machine} at the start, {machine()} at the end."
    ]
    for c, md, s in results:
        parts.append(f"#### {c.capitalize()}: `{' '.join(CONDITIONS[c]) or 'the scene (calm)'}`")
        parts.append(f"{md}\n\n({s / 60:.0f} min)")
    text = "\n\n".join(parts)
    print(text)
    if args.write_docs and not write_docs(text, BEGIN, END):
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
