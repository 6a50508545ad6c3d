"""`fpv-station export`, `fpv-station demos` and `fpv-station learn` (the `learn` extra).

    fpv-station export SESSION [SESSION ...] --format lerobot|minari|mcap --out DIR
    fpv-station export --select task=1,pilot=NAME [--include-failed] [--sessions-dir DIR]
                       [--list] --format ... --out DIR
                       [--task N] [--description TEXT] [--fps N] [--channel-map MAP]
                       [--cameras front,bottom|none] [--dataset-id ID] [--image-size WxH]
                       [--workers N] [--ray ADDRESS]
    fpv-station demos --task N --count K --out DIR [--seed S] [--cameras [NAMES]]
                      [--wind E,N] [--gusts STD] [--turbulence STD] [--random-start [DEG]]
    fpv-station learn bc DATASET --out POLICY
    fpv-station learn vision DATASET --out POLICY
    fpv-station learn eval POLICY --task N [--episodes E] [--seed S] [--demos SESSION ...]
                       [--dataset DATASET] [--wind E,N] [--gusts STD] [--turbulence STD] [--random-start [DEG]]

SESSION is a session folder, a downloaded session zip, or a bare .tlog; each flight in
it (armed, with a take-off) becomes one episode. `--select` takes the sessions of a
sessions folder by task, pilot and score instead (`analysis.selection`, the rule of the
sessions page), leaving out failed trials unless `--include-failed`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_export_arguments(p: argparse.ArgumentParser) -> None:
    from fpv_station.analysis.selection import METRICS
    from fpv_station.companion.recording.settings import RecordingSettings
    from fpv_station.learn.formats import (
        CHUNKS_SIZE,
        DATA_FILES_SIZE_IN_MB,
        DEFAULT_FPS,
        FORMATS,
        VIDEO_FILES_SIZE_IN_MB,
    )

    p.add_argument("sessions", nargs="*", type=Path, metavar="SESSION")
    p.add_argument(
        "--select",
        metavar="TERMS",
        help="export the sessions of --sessions-dir chosen by task=N, pilot=NAME, "
        f"kind=human|scripted and METRIC<=X ({', '.join(METRICS)}), comma-separated; "
        "failed trials (by the score stored at the disarm) are left out",
    )
    p.add_argument(
        "--include-failed",
        action="store_true",
        help="with --select: keep crashed, invalid and unscored trials too",
    )
    p.add_argument(
        "--sessions-dir",
        type=Path,
        default=RecordingSettings.model_fields["sessions_dir"].default,
        help="with --select: the sessions folder (default: the station's, ./sessions)",
    )
    p.add_argument(
        "--list", action="store_true", help="with --select: print the sessions, export nothing"
    )
    p.add_argument("--format", choices=FORMATS, help="required unless --list")
    p.add_argument("--out", type=Path, help="output folder (required unless --list)")
    p.add_argument(
        "--task",
        type=int,
        default=None,
        help="the scene's task id (1-4); default: the task the sessions were recorded for "
        "(sessions that do not say are refused)",
    )
    p.add_argument("--description", help="free-text task description stored with episodes")
    p.add_argument("--fps", type=int, default=DEFAULT_FPS, help="frames per second")
    p.add_argument(
        "--channel-map",
        default="AETR",
        help="RC channels of the sticks: AETR, TAER, AERT or roll=1,pitch=2,throttle=3,yaw=4",
    )
    p.add_argument("--cameras", help="cameras to export: front,bottom or none (default: all)")
    p.add_argument(
        "--image-size",
        metavar="WxH",
        help="resize camera images once, at export (for example 160x120, TwinEnv's size); "
        "default: as recorded",
    )
    p.add_argument("--dataset-id", default=None, help="dataset name (LeRobot repo id, Minari id)")
    p.add_argument(
        "--video-preset",
        default="ultrafast",
        choices=("ultrafast", "superfast", "veryfast", "faster", "fast", "medium"),
        help="x264 preset of LeRobot videos (slower = smaller files)",
    )
    p.add_argument(
        "--chunks-size",
        type=int,
        default=CHUNKS_SIZE,
        metavar="N",
        help=f"LeRobot: files per chunk folder (default {CHUNKS_SIZE}, LeRobot's)",
    )
    p.add_argument(
        "--data-files-size-mb",
        type=float,
        default=DATA_FILES_SIZE_IN_MB,
        metavar="MB",
        help="LeRobot: a data file rolls over at this size "
        f"(MiB; default {DATA_FILES_SIZE_IN_MB}, LeRobot's)",
    )
    p.add_argument(
        "--video-files-size-mb",
        type=float,
        default=VIDEO_FILES_SIZE_IN_MB,
        metavar="MB",
        help="LeRobot: a video file rolls over at this size "
        f"(MiB; default {VIDEO_FILES_SIZE_IN_MB}, LeRobot's)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="processes exporting recordings in parallel (default: the cores); the "
        "dataset is the same for any number",
    )
    p.add_argument(
        "--ray",
        metavar="ADDRESS",
        help="run the recordings' jobs on a Ray cluster ('auto', ray://HOST:10001, or "
        "'local' for a new local instance); --out must be storage every node sees",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run_export(args: argparse.Namespace) -> int:
    from fpv_station.analysis.recording import RecordingError
    from fpv_station.core.scene import SceneError
    from fpv_station.learn.episodes import ChannelMap
    from fpv_station.learn.export import (
        ExportOptions,
        default_workers,
        export_recordings,
        parse_image_size,
        tqdm_progress,
    )
    from fpv_station.learn.formats import FileLimits

    try:
        paths = selected_paths(args)
        if paths is None:
            return 0  # --list
        if args.format is None or args.out is None:
            raise ValueError("--format and --out are required")
        cmap = ChannelMap.parse(args.channel_map)
        size = parse_image_size(args.image_size) if args.image_size else None
        if args.workers is not None and args.workers < 1:
            raise ValueError("--workers must be at least 1")
        limits = FileLimits(args.chunks_size, args.data_files_size_mb, args.video_files_size_mb)
    except ValueError as exc:
        print(f"fpv-station export: {exc}", file=sys.stderr)
        return 2
    cams = None
    if args.cameras is not None:
        cams = () if args.cameras == "none" else tuple(c for c in args.cameras.split(",") if c)
    opts = ExportOptions(
        task_id=args.task,
        description=args.description,
        fps=args.fps,
        channel_map=cmap,
        cameras=cams,
        video_preset=args.video_preset,
        image_size=size,
        workers=args.workers or default_workers(),
        ray_address=args.ray,
        lerobot_limits=limits,
        **({"dataset_id": args.dataset_id} if args.dataset_id else {}),
    )
    progress = None if args.no_progress else tqdm_progress(len(paths))
    try:
        s = export_recordings(paths, args.format, args.out, opts, progress)
    except (RecordingError, SceneError, ValueError, KeyError, ImportError) as exc:
        print(f"fpv-station export: {exc}", file=sys.stderr)
        return 1
    print(
        f"{s.format}: {s.episodes} episodes ({s.frames} frames, {s.camera_frames} camera "
        f"frames) from {s.recordings} recordings -> {s.out}"
    )
    for why in s.skipped:
        print(f"skipped {why}", file=sys.stderr)
    return 0


def selected_paths(args: argparse.Namespace) -> list[Path] | None:
    """The recordings to export: the SESSION arguments, or the sessions `--select` takes
    (printed with what it left out); None after `--list`. ValueError on a bad request."""
    from fpv_station.analysis.selection import Selection, select_sessions
    from fpv_station.companion.recording.store import SessionStore

    if args.select is None:
        if args.include_failed or args.list:
            raise ValueError("--include-failed and --list go with --select")
        if not args.sessions:
            raise ValueError("give the sessions to export, or --select")
        return list(args.sessions)
    if args.sessions:
        raise ValueError("--select takes sessions from --sessions-dir; give no SESSION too")
    if not args.sessions_dir.is_dir():
        raise ValueError(f"no sessions folder '{args.sessions_dir}'; give --sessions-dir")
    store = SessionStore(args.sessions_dir)
    chosen = select_sessions(store, Selection.parse(args.select, args.include_failed))
    for sid, why in chosen.failed.items():
        print(f"left out {sid}: {why}", file=sys.stderr)
    if args.list:
        for sid in chosen.sessions:
            print(sid)
        return None
    if not chosen.sessions:
        raise ValueError(f"no session of '{args.sessions_dir}' is selected by '{args.select}'")
    return [store.resolve(sid) for sid in chosen.sessions]


def add_demos_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--task", type=int, required=True, help="the scene's task id (1-4)")
    p.add_argument("--count", type=int, required=True, help="how many flights")
    p.add_argument("--out", type=Path, required=True, help="sessions folder to write into")
    p.add_argument("--seed", type=int, default=0, help="seed of the first flight")
    p.add_argument(
        "--cameras",
        nargs="?",
        const="front,bottom",
        default=None,
        metavar="NAMES",
        help="record the cameras (default both; 'bottom' for the bottom one only)",
    )
    p.add_argument("--camera-fps", type=float, default=15.0)
    add_air_arguments(p)


def add_air_arguments(p: argparse.ArgumentParser) -> None:
    """The twin's wind and start (default: the scene's; the default field is calm)."""
    p.add_argument(
        "--wind", type=_east_north, default=(0.0, 0.0), metavar="E,N", help="mean wind (m/s)"
    )
    p.add_argument("--gusts", type=float, default=0.0, metavar="STD", help="gust std (m/s)")
    p.add_argument(
        "--turbulence", type=float, default=0.0, metavar="STD", help="turbulence std (m/s)"
    )
    p.add_argument(
        "--random-start",
        type=float,
        nargs="?",
        const=180.0,
        default=None,
        metavar="DEG",
        help="start anywhere on the pad, heading within DEG of east (default 180), seeded",
    )


def _east_north(text: str) -> tuple[float, float]:
    try:
        e, n = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not E,N in m/s (e.g. 2,0)") from None
    return e, n


def air_options(args: argparse.Namespace) -> dict:
    from fpv_station.learn.evaluate import air_options as options

    return options(args.wind, args.gusts, args.turbulence, args.random_start)


def run_demos(args: argparse.Namespace) -> int:
    from fpv_station.companion.recording.layout import CAMERAS
    from fpv_station.learn.demos import DemoConfig, fly_demos

    if args.count < 1:
        print("fpv-station demos: --count must be at least 1", file=sys.stderr)
        return 2
    cams = tuple(c for c in (args.cameras or "").split(",") if c)
    unknown = set(cams) - set(CAMERAS)
    if unknown:
        print(f"fpv-station demos: no camera {', '.join(sorted(unknown))}", file=sys.stderr)
        return 2
    config = DemoConfig(
        task_id=args.task,
        cameras=bool(cams),
        camera_names=cams or CAMERAS,
        camera_fps=args.camera_fps,
        env_options=air_options(args),
    )

    def progress(done: int, total: int) -> None:
        print(f"demos: {done}/{total}", file=sys.stderr)

    try:
        folders = fly_demos(args.out, args.count, args.seed, config, progress)
    except KeyError as exc:
        print(f"fpv-station demos: {exc}", file=sys.stderr)
        return 2
    for f in folders:
        print(f)
    return 0


def add_learn_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="learn_command", required=True)
    bc = sub.add_parser("bc", help="train a behaviour-cloning policy on a LeRobot dataset")
    bc.add_argument("dataset", type=Path, metavar="DATASET", help="a LeRobot dataset folder")
    bc.add_argument("--out", type=Path, required=True, metavar="POLICY", help="policy file")
    bc.add_argument("--k", type=int, default=5, help="neighbours averaged (default 5)")
    bc.set_defaults(func=run_bc)
    vision = sub.add_parser(
        "vision",
        help="train a policy that flies from the bottom camera and the attitude (no position) "
        "on a LeRobot dataset exported with the bottom camera",
    )
    vision.add_argument("dataset", type=Path, metavar="DATASET", help="a LeRobot dataset folder")
    vision.add_argument("--out", type=Path, required=True, metavar="POLICY", help="policy file")
    vision.add_argument("--k", type=int, default=5, help="neighbours averaged (default 5)")
    vision.set_defaults(func=run_vision)
    ev = sub.add_parser("eval", help="fly a policy in the twin; the paper's table for the task")
    ev.add_argument(
        "policy",
        type=Path,
        metavar="POLICY",
        help="a behaviour-cloning policy file, or a LeRobot policy (lerobot-train's "
        "pretrained_model folder)",
    )
    ev.add_argument("--task", type=int, required=True, help="the scene's task id (1-4)")
    ev.add_argument("--episodes", type=int, default=20)
    ev.add_argument("--seed", type=int, default=1000, help="seed of the episodes' batch")
    ev.add_argument(
        "--demos", type=Path, nargs="*", default=[], help="demonstration sessions to score too"
    )
    ev.add_argument(
        "--no-baselines",
        action="store_true",
        help="without the scripted, open-loop replay and random rows",
    )
    ev.add_argument(
        "--dataset",
        type=Path,
        metavar="DATASET",
        help="a LeRobot policy's training dataset (its fps and task text); default: the "
        "one its train_config.json names, if it is here",
    )
    add_air_arguments(ev)
    ev.set_defaults(func=run_eval)


def run_bc(args: argparse.Namespace) -> int:
    from fpv_station.learn.bc import train

    try:
        policy = train(args.dataset, args.k)
    except (ValueError, OSError) as exc:
        print(f"fpv-station learn bc: {exc}", file=sys.stderr)
        return 1
    path = policy.save(args.out)
    print(f"policy: {len(policy.inputs)} frames, k={policy.k}, task {policy.task_id} -> {path}")
    return 0


def run_vision(args: argparse.Namespace) -> int:
    from fpv_station.core.scene import SceneError
    from fpv_station.learn.vision import train

    try:
        policy = train(args.dataset, args.k)
    except (ValueError, OSError, KeyError, SceneError) as exc:
        print(f"fpv-station learn vision: {exc}", file=sys.stderr)
        return 1
    path = policy.save(args.out)
    w, h = policy.image_size
    print(
        f"vision policy: {len(policy.inputs)} frames ({w}x{h} bottom pictures), "
        f"k={policy.k}, task {policy.task_id} -> {path}"
    )
    return 0


def run_eval(args: argparse.Namespace) -> int:
    from fpv_station.core.scene import load_scene
    from fpv_station.learn import evaluate as ev

    try:
        scene = load_scene()
        scene.task(args.task)
        policy = load_policy(args.policy, args.task, args.dataset)
    except (ValueError, OSError, KeyError, ImportError) as exc:
        print(f"fpv-station learn eval: {exc}", file=sys.stderr)
        return 1
    if policy.task_id not in (0, args.task):
        print(
            f"note: the policy learned task {policy.task_id}, evaluated on task {args.task}",
            file=sys.stderr,
        )
    if args.episodes < 1:
        print("fpv-station learn eval: --episodes must be at least 1", file=sys.stderr)
        return 2
    options = air_options(args)
    try:
        batch = ev.EpisodeBatch(args.task, args.episodes, args.seed, options)
        rows = ev.benchmark(policy, batch, args.demos, baselines=not args.no_baselines)
    except (ValueError, OSError) as exc:
        print(f"fpv-station learn eval: {exc}", file=sys.stderr)
        return 1
    air = ", ".join(f"{k}: {v}" for k, v in options.items()) or "the scene's wind and start"
    print(f"Task {args.task} ({ev.TASK_NAMES[args.task]}), twin, batch seed {args.seed}, {air}:")
    print(ev.table(rows, args.task))
    for other in rows[1:]:
        if other.name in ("open-loop replay", "random") or other.name.startswith("human"):
            print(ev.compare(rows[0], other))
    return 0


def load_policy(path: Path, task_id: int, dataset: Path | None = None):
    """A LeRobot policy (a folder: `pretrained_model`, a checkpoint or a training's output,
    `learn.lerobot_policy`), else our policy file: the vision policy's or the behaviour
    clone's, told apart by its `format`."""
    from fpv_station.learn.lerobot_policy import LeRobotPolicy

    if Path(path).is_dir():
        policy = LeRobotPolicy(path, task_id, dataset)
        f = policy.facts
        print(
            f"{policy.name}: {', '.join(policy.inputs.images) or 'no'} cameras, "
            f"{f.fps:g} fps, task '{f.task}' (from {f.source})",
            file=sys.stderr,
        )
        return policy
    if dataset is not None:
        raise ValueError("--dataset is for a LeRobot policy folder")
    from fpv_station.learn.bc import BcPolicy
    from fpv_station.learn.vision import VisionPolicy, is_vision_policy

    return VisionPolicy.load(path) if is_vision_policy(path) else BcPolicy.load(path)
