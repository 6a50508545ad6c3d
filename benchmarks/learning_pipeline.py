"""The documented learning pipeline, shared by the learning benchmarks: `fpv-station demos`,
`fpv-station export --format lerobot` and `fpv-station learn ...` run in process, quietly,
as a user would type them; a failing step raises with the command's own output.

Also the benchmarks' air conditions, the machine line printed beside every figure, and
the writer of docs/LEARNING.md's generated sections.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import platform
import re
import sys
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "LEARNING.md"

# "calm" is the scene's (still air, the pad's centre facing east); "wind" is a 2 m/s mean
# from the south-west with 0.5 m/s gusts and 0.5 m/s turbulence, starting anywhere on the
# pad at any heading.
CONDITIONS = {
    "calm": [],
    "wind": ["--wind", "1.414,1.414", "--gusts", "0.5", "--turbulence", "0.5", "--random-start"],
}


def run_cli(argv: list[str]) -> str:
    """`fpv-station ARGV` in this process; its output, or RuntimeError with it."""
    from fpv_station.server.cli import main as cli

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        rc = cli(argv)
    if rc != 0:
        raise RuntimeError(f"fpv-station {argv[0]} failed ({rc}): {out.getvalue()}")
    return out.getvalue()


def fly_demos(out: Path, task: int, count: int, extra: Sequence[str] = ()) -> list[str]:
    """`fpv-station demos` (seeds 0, 1, ...) into `out`; the session folders, sorted."""
    argv = ["demos", "--task", str(task), "--count", str(count), "--seed", "0"]
    run_cli([*argv, "--out", str(out), *extra])
    return sorted(str(p) for p in out.iterdir() if p.is_dir())


def export_lerobot(sessions: list[str], out: Path, extra: Sequence[str] = ()) -> Path:
    """`fpv-station export --format lerobot` of `sessions` into `out`."""
    run_cli(
        ["export", *sessions, "--format", "lerobot", "--out", str(out), *extra, "--no-progress"]
    )
    return out


def air(condition: str) -> dict:
    """The evaluation's air options for one of CONDITIONS, parsed as `learn eval` parses them."""
    from fpv_station.learn.cli import add_air_arguments, air_options

    parser = argparse.ArgumentParser()
    add_air_arguments(parser)
    return air_options(parser.parse_args(CONDITIONS[condition]))


def machine() -> str:
    """The machine and its load, printed beside every figure."""
    load = os.getloadavg()
    return (
        f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}"
    )


def write_docs(text: str, begin: str, end: str) -> bool:
    """Put `text` into docs/LEARNING.md between the markers `begin` and `end`."""
    doc = DOCS.read_text()
    if begin not in doc or end not in doc:
        print(f"{DOCS} has no markers {begin} ... {end}", file=sys.stderr)
        return False
    pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
    DOCS.write_text(pattern.sub(lambda m: f"{begin}\n{text}\n{end}", doc))
    return True
