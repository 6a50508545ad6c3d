"""`fpv-station export`: recordings to a learning format, one episode per flight.

    export_recordings(paths, "lerobot", out_dir, ExportOptions(task_id=1))

Recordings are opened one at a time (`analysis.recording.open_recording`) and their episodes
streamed into the format's writer, so memory stays flat in the number of sessions. The
formats: `lerobot` (`learn.lerobot`), `minari` (`learn.minari_export`), `mcap`
(`learn.mcap_export`).
"""

from __future__ import annotations

import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from fpv_station.analysis.recording import Recording, RecordingError, open_recording, recording_meta
from fpv_station.core.scene import Scene, load_scene
from fpv_station.learn.episodes import COLUMNS, ChannelMap, episodes
from fpv_station.learn.formats import DEFAULT_FPS, FORMATS


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


def export_recordings(
    paths: Sequence[Path],
    fmt: str,
    out: Path,
    options: ExportOptions = ExportOptions(),
    progress: Callable[[int, int, str], None] | None = None,
) -> ExportSummary:
    if fmt not in FORMATS:
        raise ValueError(f"unknown format '{fmt}'; use one of: {', '.join(FORMATS)}")
    scene = options.scene or load_scene()
    if options.task_id is None:
        options = replace(options, task_id=recorded_task_id(paths))
    scene.task(options.task_id)  # a wrong task fails before anything is written
    task = options.description or task_description(scene, options.task_id)
    summary = ExportSummary(Path(out), fmt)
    writer = None
    cameras = options.cameras
    for k, path in enumerate(paths):
        with open_recording(path, COLUMNS) as rec:
            if cameras is None:
                cameras = tuple(rec.cameras)
            missing = [c for c in cameras if c not in rec.cameras]
            if missing:
                raise RecordingError(
                    f"'{rec.source}' has no frames of camera {', '.join(missing)}; export "
                    "recordings with the same cameras, or choose them with --cameras."
                )
            if writer is None:
                writer = _writer(fmt, Path(out), options, scene, rec, cameras, task)
            found = 0
            for ep in episodes(
                rec, scene, options.task_id, options.fps, options.channel_map, cameras
            ):
                writer.add(rec, ep)
                found += 1
                summary.episodes += 1
                summary.frames += len(ep)
                summary.camera_frames += writer.camera_frames(rec, ep)
            if not found:
                summary.skipped.append(f"{rec.source}: no flight (armed with a take-off)")
            summary.recordings += 1
        if progress is not None:
            progress(k + 1, len(paths), str(path))
    if writer is None:
        raise RecordingError("no recording to export")
    writer.close(summary)
    return summary


def _writer(fmt, out, options, scene, rec: Recording, cameras, task):
    if fmt == "lerobot":
        from fpv_station.learn.lerobot import LeRobotExport

        return LeRobotExport(out, options, scene, rec, cameras, task)
    if fmt == "minari":
        from fpv_station.learn.minari_export import MinariExport

        return MinariExport(out, options, scene, task)
    from fpv_station.learn.mcap_export import McapExport

    return McapExport(out, options, scene, cameras, task)


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
