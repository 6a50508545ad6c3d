"""`fpv-station export`: recordings to a learning format, one episode per flight.

    export_recordings(paths, "lerobot", out_dir, ExportOptions(task_id=1, workers=4))

Each recording is one job (`export_recording`): opened (`analysis.recording.open_recording`),
split into episodes, and each episode made into the format's part: for LeRobot its rows
and its videos encoded to part files, for Minari its episode, for MCAP its finished file.
Jobs run in this process, in `workers` processes, or as tasks on a Ray cluster
(`learn.export_ray`); their results come back in the recordings' order, at most two per
worker ahead, and one process adds them to the dataset (its metadata: indices, files,
stats). The dataset is the same whichever ran the jobs, and memory stays flat in the
number of recordings. The formats: `lerobot` (`learn.lerobot`), `minari`
(`learn.minari_export`), `mcap` (`learn.mcap_export`).
"""

from __future__ import annotations

import multiprocessing
import os
import re
import sys
import tempfile
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

from fpv_station.analysis.recording import RecordingError, open_recording, recording_meta
from fpv_station.core.scene import Scene, load_scene
from fpv_station.learn.episodes import COLUMNS, ChannelMap, Episode, episodes
from fpv_station.learn.formats import DEFAULT_FPS, FORMATS, FileLimits

JOBS_AHEAD = 2  # results a worker may run ahead of the one being added


@dataclass(frozen=True)
class ExportOptions:
    # The scene's task; None: the task the sessions were recorded for (session.json
    # `task`: chosen on the pilot page, or flown by `demos`), never a guess.
    task_id: int | None = None
    description: str | None = None  # free text; default: the scene's task name and procedure
    fps: int = DEFAULT_FPS
    channel_map: ChannelMap = field(default_factory=ChannelMap)
    cameras: tuple[str, ...] | None = None  # None: the cameras of the first recording
    dataset_id: str = "fpv-station/demonstrations"
    video_preset: str = "ultrafast"  # x264 preset of LeRobot videos
    # (width, height) every camera image is resized to, once, as it is exported (LeRobot
    # videos; MCAP images re-encoded as JPEG); None: as recorded (MCAP: the bytes as is).
    image_size: tuple[int, int] | None = None
    lerobot_limits: FileLimits = field(default_factory=FileLimits)
    workers: int = 1  # processes that run recordings' jobs; 1: this process
    ray_address: str | None = None  # run the jobs on this Ray cluster instead
    scene: Scene | None = None


@dataclass
class ExportSummary:
    out: Path
    format: str
    recordings: int = 0
    episodes: int = 0
    frames: int = 0  # dataset frames (rows)
    camera_frames: int = 0  # video frames written (or JPEGs copied, for MCAP)
    skipped: list[str] = field(default_factory=list)  # recordings without a flight, and why


def parse_image_size(text: str) -> tuple[int, int]:
    """`160x120` -> (160, 120): width and height, even (H.264's 4:2:0 needs them so)."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if m is None:
        raise ValueError(f"image size '{text}': give WIDTHxHEIGHT, for example 160x120")
    w, h = int(m.group(1)), int(m.group(2))
    if not (2 <= w <= 4096 and 2 <= h <= 4096) or w % 2 or h % 2:
        raise ValueError(f"image size '{text}': width and height are even, from 2 to 4096")
    return w, h


def task_description(scene: Scene, task_id: int) -> str:
    t = scene.task(task_id)
    return " ".join([f"{t.name}:", *t.procedure]) if t.procedure else t.name


def recorded_task_id(paths: Sequence[Path]) -> int:
    """The one flight task the recordings were made for (session.json `task`). A task is
    never guessed: a recording that does not say (a bare tlog, a session recorded with no
    task chosen) is refused, as are recordings of different tasks together (a Minari
    dataset is one task's environment); `--task` chooses it for them."""
    ids: set[int] = set()
    unknown: list[str] = []
    for path in paths:
        task = recording_meta(path).get("task")
        if isinstance(task, dict) and isinstance(task.get("id"), int):
            ids.add(task["id"])
        else:
            unknown.append(Path(path).name)
    if unknown:
        raise RecordingError(
            f"{', '.join(unknown)}: no task recorded in session.json, so the episodes' task "
            "(its text, and the pad the state is measured from) is unknown; give it with "
            "--task N."
        )
    if len(ids) > 1:
        raise RecordingError(
            f"these recordings were flown for tasks {sorted(ids)}: export each task's "
            "recordings separately, or choose one with --task."
        )
    return ids.pop()


def default_workers() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


@dataclass(frozen=True)
class RecordingJob:
    """One recording to export: all a worker process (or a Ray task) needs."""

    index: int  # the recording's place in the export
    path: Path
    fmt: str
    out: Path
    parts: Path  # a folder for part files (on a cluster: storage every node sees)
    options: ExportOptions  # with its task and scene resolved, as below
    cameras: tuple[str, ...]
    sizes: dict[str, tuple[int, int]]  # camera -> (width, height) of LeRobot videos
    task: str
    scene: Scene
    task_id: int


@dataclass
class RecordingResult:
    source: str
    parts: list = field(default_factory=list)  # per episode, the format's part
    frames: int = 0
    camera_frames: int = 0


def export_recording(job: RecordingJob) -> RecordingResult:
    """A recording's episodes as the format's parts (runs in any process)."""
    o = job.options
    with open_recording(job.path, COLUMNS) as rec:
        missing = [c for c in job.cameras if c not in rec.cameras]
        if missing:
            raise RecordingError(
                f"'{rec.source}' has no frames of camera {', '.join(missing)}; export "
                "recordings with the same cameras, or choose them with --cameras."
            )
        result = RecordingResult(rec.source)
        for ep in episodes(rec, job.scene, job.task_id, o.fps, o.channel_map, job.cameras):
            result.parts.append(_part(job, rec, ep))
            result.frames += len(ep)
            result.camera_frames += _camera_frames(job, rec, ep)
    return result


def _part(job: RecordingJob, rec, ep: Episode):
    o = job.options
    if job.fmt == "lerobot":
        from fpv_station.learn.lerobot import episode_part
        from fpv_station.learn.onboard_export import series_part

        tag = f"{job.index:06d}_{ep.number:03d}"
        part = episode_part(ep, rec.frame_bytes, job.sizes, o.fps, o.video_preset, job.parts, tag)
        return replace(part, onboard=series_part(rec, ep.t_s, job.parts, tag))
    if job.fmt == "minari":
        return ep
    from fpv_station.learn.mcap_export import mcap_name, write_episode_mcap
    from fpv_station.learn.onboard_export import onboard_of

    path = job.parts / f"{job.index:06d}_{ep.number:03d}.mcap"
    onboard = onboard_of(rec)
    write_episode_mcap(
        path, rec, ep, job.scene, job.task_id, job.cameras, job.task, o.image_size, onboard
    )
    return path, mcap_name(rec, ep)


def _camera_frames(job: RecordingJob, rec, ep: Episode) -> int:
    if job.fmt == "lerobot":
        return len(ep) * len(job.cameras)
    if job.fmt == "mcap":
        from fpv_station.learn.mcap_export import frame_window

        return sum(int(frame_window(rec, c, ep).size) for c in job.cameras)
    return 0


def export_recordings(
    paths: Sequence[Path],
    fmt: str,
    out: Path,
    options: ExportOptions = ExportOptions(),
    progress: Callable[[int, int, str], None] | None = None,
) -> ExportSummary:
    if fmt not in FORMATS:
        raise ValueError(f"unknown format '{fmt}'; use one of: {', '.join(FORMATS)}")
    if not paths:
        raise RecordingError("no recording to export")
    if options.workers < 1:
        raise ValueError(f"workers must be at least 1, not {options.workers}")
    scene = options.scene or load_scene()
    task_id = options.task_id if options.task_id is not None else recorded_task_id(paths)
    scene.task(task_id)  # a wrong task fails before anything is written
    options = replace(options, scene=scene, task_id=task_id)
    task = options.description or task_description(scene, task_id)
    cameras, sizes = _cameras(paths[0], options)
    out = Path(out)
    writer = _assembler(fmt, out, options, sizes, task)
    summary = ExportSummary(out, fmt)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".parts-", dir=out) as parts:
        jobs = [
            RecordingJob(
                k, Path(p), fmt, out, Path(parts), options, cameras, sizes, task, scene, task_id
            )
            for k, p in enumerate(paths)
        ]
        for k, result in enumerate(_results(jobs, options)):
            for part in result.parts:
                writer.add(part)
            summary.episodes += len(result.parts)
            summary.frames += result.frames
            summary.camera_frames += result.camera_frames
            if not result.parts:
                summary.skipped.append(f"{result.source}: no flight (armed with a take-off)")
            summary.recordings += 1
            if progress is not None:
                progress(k + 1, len(paths), str(paths[k]))
    writer.close(summary)
    return summary


def _cameras(first: Path, options: ExportOptions):
    """The cameras to export (given, or those of the first recording) and each one's
    LeRobot video size (given, or as the first recording has it)."""
    cameras = options.cameras
    if cameras == () or (cameras is None and Path(first).suffix.lower() == ".tlog"):
        return (), {}  # a tlog has no frames
    with open_recording(first, frames=True) as rec:
        if cameras is None:
            cameras = tuple(rec.cameras)
        missing = [c for c in cameras if c not in rec.cameras]
        if missing:
            raise RecordingError(
                f"'{rec.source}' has no frames of camera {', '.join(missing)}; export "
                "recordings with the same cameras, or choose them with --cameras."
            )
        sizes = {
            c: options.image_size or (rec.cameras[c].width, rec.cameras[c].height) for c in cameras
        }
    return cameras, sizes


def _results(jobs: list[RecordingJob], options: ExportOptions) -> Iterator[RecordingResult]:
    """The jobs' results in the jobs' order."""
    if options.ray_address:
        from fpv_station.learn.export_ray import ray_results

        yield from ray_results(export_recording, jobs, options.ray_address, JOBS_AHEAD)
    elif options.workers == 1 or len(jobs) == 1:
        yield from map(export_recording, jobs)
    else:
        yield from _pool_results(jobs, min(options.workers, len(jobs)))


def _pool_results(jobs: list[RecordingJob], workers: int) -> Iterator[RecordingResult]:
    # Fresh interpreters, not forks: the parent may hold threads (OpenCV's, PyAV's)
    # whose locks a fork would copy held.
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context) as pool:
        pending: deque[Future[RecordingResult]] = deque()
        todo = iter(jobs)
        try:
            for job in todo:
                pending.append(pool.submit(export_recording, job))
                if len(pending) >= workers * JOBS_AHEAD:
                    break
            while pending:
                result = pending.popleft().result()
                for job in todo:
                    pending.append(pool.submit(export_recording, job))
                    break
                yield result
        finally:
            for f in pending:
                f.cancel()


def _assembler(fmt, out, options, sizes, task):
    if fmt == "lerobot":
        from fpv_station.learn.lerobot import LeRobotExport

        return LeRobotExport(out, options, sizes, task)
    if fmt == "minari":
        from fpv_station.learn.minari_export import MinariExport

        return MinariExport(out, options, options.scene, task)
    from fpv_station.learn.mcap_export import McapExport

    return McapExport(out)


def tqdm_progress(total: int):
    """A progress bar on stderr (tqdm), as a `progress` callback."""
    from tqdm import tqdm

    bar = tqdm(total=total, unit="recording", file=sys.stderr, dynamic_ncols=True)

    def update(done: int, n: int, name: str) -> None:
        bar.set_postfix_str(Path(name).name[-40:])
        bar.update(done - bar.n)
        if done == n:
            bar.close()

    return update
