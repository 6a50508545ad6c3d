"""`fpv-station analyze`: the paper's task analysis of one or more sessions.

    fpv-station analyze SESSION [SESSION ...] --task {hover,a-to-b,obstacle,figure8}
                        [--reference LAT,LON] [--out DIR] [--scene FILE | --no-scene]
                        [--label NAME ...] [--hover-height M] [--hover-window S]
                        [--hover-tolerance M]
                        [--margin M] [--airborne-height M] [--height-source pilot|gps]
                        [--flight N]

SESSION is a session folder, a downloaded session zip, or a bare .tlog. Each flight in
it (take-off to landing; an autopilot's log often holds several) is one row, labelled
"SESSION flight N"; --flight N analyses only the N-th of each. Prints the comparison
table (Markdown) and writes it as .md/.csv/.json with the three figures.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from fpv_station.analysis.errors import AnalysisError
from fpv_station.analysis.tasks import TASKS, TaskParams
from fpv_station.core.geodesy import LatLonError, parse_latlon


def _latlon_arg(text: str) -> tuple[float, float]:
    try:
        return parse_latlon(text)
    except LatLonError as exc:  # argparse shows an ArgumentTypeError's own message
        raise argparse.ArgumentTypeError(str(exc)) from None


def _flight_arg(text: str) -> int:
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"--flight counts from 1, not '{text}'.")
    return int(text)


def add_arguments(p: argparse.ArgumentParser) -> None:
    d = TaskParams()
    p.add_argument(
        "sessions",
        nargs="+",
        type=Path,
        metavar="SESSION",
        help="session folder, session .zip or .tlog",
    )
    # Not `choices=`: a wrong task gets the same clear message as through REST.
    p.add_argument("--task", required=True, help=f"one of: {', '.join(TASKS)}")
    p.add_argument(
        "--reference",
        type=_latlon_arg,
        metavar="LAT,LON",
        help="point that sets +x (default: the scene's landing pad, else the landing point)",
    )
    p.add_argument("--out", type=Path, help="output folder (default: ./analysis-TASK)")
    scene = p.add_mutually_exclusive_group()
    scene.add_argument("--scene", type=Path, help="twin scene TOML with pads and obstacles")
    scene.add_argument("--no-scene", action="store_true", help="ignore the field layout")
    p.add_argument("--label", action="append", help="name of each session, in order")
    p.add_argument("--hover-height", type=float, default=d.hover_height_m, metavar="M")
    p.add_argument("--hover-window", type=float, default=d.hover_window_s, metavar="S")
    p.add_argument(
        "--hover-tolerance",
        type=float,
        default=d.hover_height_tolerance_m,
        metavar="M",
        help="the hover starts at hover height minus this",
    )
    p.add_argument(
        "--margin",
        type=float,
        default=d.margin_m,
        metavar="M",
        help="window starts/ends this far along x from take-off/landing",
    )
    p.add_argument(
        "--flight",
        type=_flight_arg,
        metavar="N",
        help="analyse only the N-th flight of each session (default: every flight, one row each)",
    )
    p.add_argument("--airborne-height", type=float, default=d.airborne_height_m, metavar="M")
    p.add_argument(
        "--height-source",
        choices=("pilot", "gps"),
        default=d.height_source,
        help="height that decides take-off, landing, the hover start and contacts: "
        "the pilot's recorded altitude (default) or GPS",
    )


def run(args: argparse.Namespace) -> int:
    from fpv_station.analysis.report import analyze_paths

    params = TaskParams(
        hover_height_m=args.hover_height,
        hover_window_s=args.hover_window,
        hover_height_tolerance_m=args.hover_tolerance,
        margin_m=args.margin,
        airborne_height_m=args.airborne_height,
        height_source=args.height_source,
    )
    scene: Any = False if args.no_scene else (args.scene if args.scene else True)
    try:
        analysis = analyze_paths(
            args.sessions, args.task, args.reference, scene, params, args.label, args.flight
        )
        out = args.out or Path(f"analysis-{args.task}")
        files = analysis.write(out)
        files += write_onboard_figures(args.sessions, out)
    except (AnalysisError, OSError) as exc:
        print(f"fpv-station analyze: {exc}", file=sys.stderr)
        return 2
    print(analysis.comparison.to_markdown())
    for label, why in analysis.skipped:
        print(f"skipped {label}: {why}", file=sys.stderr)
    for f in files:
        print(f"wrote {f}")
    return 0


def write_onboard_figures(sessions: list[Path], out: Path) -> list[Path]:
    """`<session>_onboard.png` for each session folder that holds the autopilot's log."""
    from fpv_station.analysis.onboard_log import OnboardLogError, find_onboard_log, session_onboard
    from fpv_station.analysis.onboard_plots import onboard_figure
    from fpv_station.analysis.recording import open_recording

    files = []
    for path in map(Path, sessions):
        if not path.is_dir() or find_onboard_log(path) is None:
            continue
        try:
            with open_recording(path, frames=False) as rec:
                onboard = session_onboard(rec)
                name = rec.name
            if onboard is None or onboard.clock is None:
                continue
            png = onboard_figure(onboard, name)
        except (OnboardLogError, ValueError) as exc:
            print(f"fpv-station analyze: {path}: no onboard figure: {exc}", file=sys.stderr)
            continue
        target = out / f"{name}_onboard.png"
        target.write_bytes(png)
        files.append(target)
    return files
