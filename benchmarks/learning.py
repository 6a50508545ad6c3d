"""The learning benchmark of docs/LEARNING.md: tasks 1-4, in calm air and in wind.

    python benchmarks/learning.py [--episodes 20] [--demos 10] [--jobs 2] [--write-docs]

Per condition and task, the documented commands, in process: `fpv-station demos` flies
`--demos` demonstrations (seeds 0, 1, ...) in the condition's air, `fpv-station export`
makes a LeRobot dataset of them (no cameras), `fpv-station learn bc` trains the clone, and
`learn eval`'s rows fly `--episodes` episodes (one batch, seed 1000): behaviour cloning,
the scripted pilot, the open-loop replay of the demonstrations' sticks, random sticks,
and the demonstrations themselves. Prints the Markdown tables with 95 % intervals, the
clone against the replay and random (Newcombe's interval of the success difference),
the machine, its load and the time taken; `--write-docs` puts them into docs/LEARNING.md
between its benchmark markers.

Conditions: "calm" is the scene's (still air, the pad's centre facing east); "wind" is a
2 m/s mean from the south-west with 0.5 m/s gusts and 0.5 m/s turbulence, starting
anywhere on the pad at any heading. Units run in `--jobs` processes.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CONDITIONS = {
    "calm": [],
    "wind": ["--wind", "1.414,1.414", "--gusts", "0.5", "--turbulence", "0.5", "--random-start"],
}
DOCS = ROOT / "docs" / "LEARNING.md"
BEGIN, END = "<!-- benchmarks/learning.py: begin -->", "<!-- benchmarks/learning.py: end -->"


def unit(condition: str, task: int, demos: int, episodes: int) -> tuple[str, int, str, float]:
    """One condition and task: demos, export, clone, evaluation; (condition, task, Markdown,
    seconds)."""
    import contextlib
    import io

    from fpv_station.learn import evaluate as ev
    from fpv_station.learn.bc import BcPolicy
    from fpv_station.learn.cli import air_options
    from fpv_station.server.cli import main as cli

    t0 = time.perf_counter()
    air = CONDITIONS[condition]
    with tempfile.TemporaryDirectory(prefix=f"learning-{condition}-{task}-") as tmp_name:
        tmp = Path(tmp_name)
        quiet = io.StringIO()
        with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
            argv = ["demos", "--task", str(task), "--count", str(demos), "--seed", "0"]
            if cli([*argv, "--out", str(tmp / "demos"), *air]) != 0:
                raise RuntimeError(f"demos failed: {quiet.getvalue()}")
            sessions = sorted(str(p) for p in (tmp / "demos").iterdir() if p.is_dir())
            argv = ["export", *sessions, "--format", "lerobot", "--out", str(tmp / "ds")]
            if cli([*argv, "--no-progress"]) != 0:
                raise RuntimeError(f"export failed: {quiet.getvalue()}")
            if cli(["learn", "bc", str(tmp / "ds"), "--out", str(tmp / "policy.npz")]) != 0:
                raise RuntimeError(f"learn bc failed: {quiet.getvalue()}")
        policy = BcPolicy.load(tmp / "policy.npz")
        parser = argparse.ArgumentParser()
        from fpv_station.learn.cli import add_air_arguments

        add_air_arguments(parser)
        options = air_options(parser.parse_args(air))
        rows = ev.benchmark(policy, task, episodes, 1000, options, [Path(s) for s in sessions])
    by_name = {r.name: r for r in rows}
    lines = [
        f"Task {task} ({ev.TASK_NAMES[task]}), {condition}: {demos} demonstrations "
        f"({len(policy.inputs)} frames), {episodes} episodes per flown row, batch seed 1000.",
        "",
        ev.table(rows, task),
        "",
        *(
            f"- {ev.compare(by_name['behaviour cloning'], by_name[o])}"
            for o in ("open-loop replay", "random")
        ),
    ]
    return condition, task, "\n".join(lines), time.perf_counter() - t0


def machine() -> str:
    load = os.getloadavg()
    return (
        f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--episodes", type=int, default=20, help="episodes per flown row")
    ap.add_argument("--demos", type=int, default=10, help="demonstrations per task")
    ap.add_argument("--tasks", default="1,2,3,4")
    ap.add_argument("--conditions", default="calm,wind", help="of: " + ", ".join(CONDITIONS))
    ap.add_argument("--jobs", type=int, default=2, help="processes")
    ap.add_argument("--write-docs", action="store_true", help="update docs/LEARNING.md")
    args = ap.parse_args()
    tasks = [int(t) for t in args.tasks.split(",")]
    conditions = args.conditions.split(",")
    units = [(c, t) for t in tasks for c in conditions]  # the short tasks first
    start_machine, t0 = machine(), time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        futures = [pool.submit(unit, c, t, args.demos, args.episodes) for c, t in units]
        results = []
        for f in futures:  # each as it comes, so that a cut-short run keeps what it made
            results.append(f.result())
            c, t, md, s = results[-1]
            print(f"[{c} task {t}: {s:.0f} s, {machine()}]\n{md}\n", file=sys.stderr, flush=True)
    wall = time.perf_counter() - t0
    parts = [
        f"Generated by `python benchmarks/learning.py --episodes {args.episodes} "
        f"--demos {args.demos} --jobs {args.jobs}{' --write-docs' if args.write_docs else ''}` "
        f"in {wall / 60:.0f} min on {start_machine} at the start, {machine()} at the end.",
    ]
    for c in conditions:
        parts.append(f"#### {c.capitalize()}: `{' '.join(CONDITIONS[c]) or 'the scene (calm)'}`")
        parts += [md for cc, _, md, _ in sorted(results) if cc == c]
    text = "\n\n".join(parts)
    print(text)
    if args.write_docs and not write_docs(text, BEGIN, END):
        return 1
    return 0


def write_docs(text: str, begin: str, end: str) -> bool:
    """Put `text` into docs/LEARNING.md between the markers `begin` and `end`."""
    doc = DOCS.read_text()
    if begin not in doc or end not in doc:
        print(f"{DOCS} has no markers {begin} ... {end}", file=sys.stderr)
        return False
    pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
    DOCS.write_text(pattern.sub(lambda m: f"{begin}\n{text}\n{end}", doc))
    return True


if __name__ == "__main__":
    sys.exit(main())
