"""A LeRobot dataset (format v3.0), written with pyarrow and PyAV (no `lerobot`, no torch).

The layout is LeRobot's v3.0 (`LeRobotDataset(repo_id, root=DIR)` loads it):

    meta/info.json                       codebase_version "v3.0", fps, features, path templates,
                                         chunks_size, data/video file size limits
    meta/stats.json                      per feature: min, max, mean, std, count, q01..q99
    meta/tasks.parquet                   task text (the pandas index) -> task_index
    meta/episodes/chunk-000/file-000.parquet   one row per episode: length, tasks, where its
                                         rows and video frames are, its own stats
    data/chunk-CCC/file-FFF.parquet      one row per frame, one row group per episode
    videos/observation.images.front/chunk-CCC/file-FFF.mp4   episodes back to back
    videos/observation.images.bottom/chunk-CCC/file-FFF.mp4
    README.md                            the dataset card

Rows: `observation.state` (the twin env's state vector, `twin.gym_env.STATE_NAMES`),
`action` (roll, pitch, yaw, throttle in [-1, 1]), `timestamp` (s since the episode's
first frame, as LeRobot needs to find video frames: `from_timestamp + timestamp`),
`session_time_s` (the same instant on the recording's session clock), `frame_index`,
`episode_index`, `index` (over the dataset), `task_index`, `next.done`.

Writing is in two steps, as LeRobot's own writer does it:
- `episode_part` (any process): an episode's rows as arrays, and per camera its video
  encoded alone to a part file. Frame k of the dataset is the recorded JPEG shown at that
  instant (`learn.episodes`), decoded once (resized to the dataset's size if it differs)
  and encoded to H.264 (yuv420p, a keyframe every 2 frames as LeRobot's encoder uses, so
  random access stays cheap; x264 preset `--video-preset`, default ultrafast), with the
  pixel histogram of every frame for the image stats.
- `LeRobotWriter.add_episode` (one process, in the recordings' order): the rows appended
  to the current data file and each part's packets to the camera's current video file,
  unchanged (no re-encode). A file rolls over by LeRobot's rule: a new one when the
  current file's size plus the episode's would reach `data_files_size_in_mb` (data:
  the current file's bytes per frame times the episode's frames) or
  `video_files_size_in_mb` (video: the part's bytes). File indices count up to
  `chunks_size - 1`, then the chunk index moves on (LeRobot's
  `update_chunk_file_indices`). An episode never spans two files; its video times start
  at `from_timestamp`, the frames before it in its file over the fps.
So the output is the same whichever process encoded which part. Memory does not grow
with the number of episodes but for their metadata rows.
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Final

import av
import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fpv_station.learn import stats as st
from fpv_station.learn.episodes import Episode
from fpv_station.learn.formats import FileLimits
from fpv_station.learn.images import decode_fit
from fpv_station.learn.onboard_export import OnboardSeries, lerobot_card_section, place_series
from fpv_station.twin.gym_env import ACTION_NAMES, STATE_NAMES

CODEBASE_VERSION = "v3.0"
MB = 1024 * 1024  # LeRobot's megabyte (get_file_size_in_mb)
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_CODEC: Final = "libx264"
VIDEO_OPTIONS = {"g": "2", "crf": "23"}
# x264's fastest preset keeps a two-camera export over 10x real time on a 2-core machine;
# "veryfast" makes files ~45% smaller at about twice the encoding time.
VIDEO_PRESET = "ultrafast"
ROBOT_TYPE = "f450_quadcopter"

FrameSource = Callable[[int], bytes]  # recorded frame index -> JPEG bytes


@dataclass(frozen=True)
class DatasetMeta:
    """What a learner needs of a LeRobot dataset's metadata besides its frames."""

    fps: int
    tasks: list[str]  # by task_index
    task_id: int  # the scene's task of `export`'s episodes (0: unknown)
    features: dict[str, dict]


def read_meta(root: Path) -> DatasetMeta:
    """meta/info.json, meta/tasks.parquet and the episodes' `source/task_id`."""
    root = Path(root)
    try:
        info = json.loads((root / "meta" / "info.json").read_text())
        fps, features = int(info["fps"]), dict(info["features"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"'{root}' is not a LeRobot dataset (meta/info.json: {exc})") from None
    tasks: list[str] = []
    if (root / "meta" / "tasks.parquet").is_file():
        t = pq.read_table(root / "meta" / "tasks.parquet", columns=["task_index", "task"])
        tasks = [v for _, v in sorted(zip(t["task_index"].to_pylist(), t["task"].to_pylist()))]
    task_id = 0
    episodes = sorted((root / "meta" / "episodes").glob("*/*.parquet"))
    if episodes and "source/task_id" in pq.read_schema(episodes[0]).names:
        task_id = int(pq.read_table(episodes[0], columns=["source/task_id"])[0][0].as_py())
    return DatasetMeta(fps, tasks, task_id, features)


def video_key(camera: str) -> str:
    return f"observation.images.{camera}"


def next_file(chunk: int, file: int, chunks_size: int) -> tuple[int, int]:
    """The (chunk, file) index after this one, as LeRobot's `update_chunk_file_indices`."""
    return (chunk + 1, 0) if file == chunks_size - 1 else (chunk, file + 1)


@dataclass
class EpisodeVideo:
    """One camera's frames of one episode, encoded alone to a part file."""

    path: Path
    frames: int
    hist: np.ndarray  # (3, 256) RGB pixel counts over every frame (`stats.image_histogram`)


@dataclass
class EpisodePart:
    """An episode ready for `LeRobotWriter.add_episode`: rows as arrays, videos as parts.
    Made wherever the work runs (`episode_part`); small but for the part files."""

    recording: str
    number: int
    landed: bool
    t_s: np.ndarray
    state: np.ndarray
    action: np.ndarray
    videos: dict[str, EpisodeVideo] = field(default_factory=dict)
    onboard: OnboardSeries | None = None  # the autopilot log's series (learn.onboard_export)

    def __len__(self) -> int:
        return int(self.t_s.size)


def episode_part(
    ep: Episode,
    frame_bytes: Callable[[str, int], bytes],
    sizes: dict[str, tuple[int, int]],
    fps: int,
    preset: str,
    parts: Path,
    tag: str,
) -> EpisodePart:
    """Encode an episode's camera frames (`sizes`: camera -> (width, height)) to part
    files `parts/{tag}_{camera}.mp4`."""
    videos = {}
    if len(ep):
        for cam, size in sizes.items():
            path = Path(parts) / f"{tag}_{cam}.mp4"
            videos[cam] = encode_video(
                path, ep.frames[cam], functools.partial(frame_bytes, cam), size, fps, preset
            )
    return EpisodePart(ep.recording, ep.number, ep.landed, ep.t_s, ep.state, ep.action, videos)


def encode_video(
    path: Path,
    picks: np.ndarray,
    jpeg: FrameSource,
    size: tuple[int, int],
    fps: int,
    preset: str = VIDEO_PRESET,
) -> EpisodeVideo:
    """The recorded frames `picks` (one per dataset frame) as an H.264 file at `size`."""
    total = np.zeros((3, 256), np.int64)
    time_base = Fraction(1, fps)
    with av.open(str(path), mode="w") as container:
        stream = container.add_stream(
            VIDEO_CODEC, rate=fps, options={**VIDEO_OPTIONS, "preset": preset}
        )
        stream.width, stream.height = size
        stream.pix_fmt = "yuv420p"
        last = None
        frame: av.VideoFrame | None = None
        for i, k in enumerate(picks):
            # A recorded frame held over several dataset frames is converted once.
            if frame is None or k != last:
                bgr = decode_fit(jpeg(int(k)), size)
                # OpenCV's I420 conversion is BT.601 limited range, what an untagged H.264
                # stream is decoded as, and several times faster than swscale from BGR.
                i420 = np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV_I420), np.uint8)
                frame = av.VideoFrame.from_ndarray(i420, format="yuv420p")
                frame.time_base = time_base
                hist = st.image_histogram(bgr)[::-1]  # BGR -> RGB
                last = k
            total += hist
            frame.pts = i  # the encoder takes its own reference: reuse is safe
            container.mux(stream.encode(frame))
        container.mux(stream.encode(None))
    return EpisodeVideo(Path(path), len(picks), total)


class LeRobotWriter:
    def __init__(
        self,
        root: Path,
        fps: int,
        cameras: dict[str, tuple[int, int]],  # camera -> (width, height)
        robot_type: str = ROBOT_TYPE,
        task_id: int = 0,
        limits: FileLimits | None = None,
    ) -> None:
        limits = limits or FileLimits()
        self.root = Path(root)
        self.task_id = task_id  # the scene's task, kept per episode for the baseline
        self.fps = int(fps)
        self.cameras = dict(cameras)
        self.robot_type = robot_type
        self.limits = limits
        self.root.mkdir(parents=True, exist_ok=True)
        self.features = self._features()
        self._schema = pa.schema(
            [
                ("observation.state", pa.list_(pa.float32(), len(STATE_NAMES))),
                ("action", pa.list_(pa.float32(), len(ACTION_NAMES))),
                ("timestamp", pa.float32()),
                ("session_time_s", pa.float64()),
                ("frame_index", pa.int64()),
                ("episode_index", pa.int64()),
                ("index", pa.int64()),
                ("task_index", pa.int64()),
                ("next.done", pa.bool_()),
            ]
        )
        self._data = _DataFiles(self.root, self._schema, limits)
        self._videos = {c: _VideoFiles(self.root, c, self.fps, limits) for c in self.cameras}
        self.tasks: dict[str, int] = {}
        self.episodes: list[dict] = []
        self._episode_stats: list[dict[str, st.Stats]] = []
        # Per camera, the pixel histogram of every frame so far: the dataset's image stats.
        self._image_hist = {c: np.zeros((3, 256), np.int64) for c in self.cameras}
        self.total_frames = 0

    # ------------------------------------------------------------------ episodes

    def add_episode(self, ep: EpisodePart, task: str) -> None:
        """Append an episode; its part files are moved into the dataset's videos (and
        deleted)."""
        n = len(ep)
        if n == 0:
            return
        index = len(self.episodes)
        task_index = self.tasks.setdefault(task, len(self.tasks))
        frame_index = np.arange(n, dtype=np.int64)
        timestamp = (frame_index / self.fps).astype(np.float32)
        done = np.zeros(n, bool)
        done[-1] = True
        columns = {
            "observation.state": _fixed_list(ep.state),
            "action": _fixed_list(ep.action),
            "timestamp": pa.array(timestamp),
            "session_time_s": pa.array(ep.t_s),
            "frame_index": pa.array(frame_index),
            "episode_index": pa.array(np.full(n, index, np.int64)),
            "index": pa.array(self.total_frames + frame_index),
            "task_index": pa.array(np.full(n, task_index, np.int64)),
            "next.done": pa.array(done),
        }
        chunk, file = self._data.write(pa.table(columns, schema=self._schema))
        ep_stats = {
            "observation.state": st.vector_stats(ep.state),
            "action": st.vector_stats(ep.action),
            "timestamp": st.vector_stats(timestamp[:, None]),
            "session_time_s": st.vector_stats(ep.t_s[:, None]),
            "frame_index": st.vector_stats(frame_index[:, None]),
            "episode_index": st.vector_stats(np.full((n, 1), index)),
            "index": st.vector_stats((self.total_frames + frame_index)[:, None]),
            "task_index": st.vector_stats(np.full((n, 1), task_index)),
            "next.done": st.vector_stats(done[:, None]),
        }
        meta = {
            "episode_index": index,
            "tasks": [task],
            "length": n,
            "data/chunk_index": chunk,
            "data/file_index": file,
            "dataset_from_index": self.total_frames,
            "dataset_to_index": self.total_frames + n,
        }
        for cam, files in self._videos.items():
            part = ep.videos[cam]
            if part.frames != n:
                raise ValueError(f"{cam} video of {part.frames} frames for {n} rows")
            chunk, file, start = files.append(part.path, n)
            self._image_hist[cam] += part.hist
            ep_stats[video_key(cam)] = st.histogram_stats(part.hist, n)
            meta.update(
                {
                    f"videos/{video_key(cam)}/chunk_index": chunk,
                    f"videos/{video_key(cam)}/file_index": file,
                    f"videos/{video_key(cam)}/from_timestamp": start / self.fps,
                    f"videos/{video_key(cam)}/to_timestamp": (start + n) / self.fps,
                }
            )
        meta["meta/episodes/chunk_index"] = 0
        meta["meta/episodes/file_index"] = 0
        for feature, s in ep_stats.items():
            for key, value in s.items():
                meta[f"stats/{feature}/{key}"] = np.asarray(value).tolist()
        meta["source/recording"] = ep.recording
        meta["source/flight"] = ep.number
        meta["source/landed"] = ep.landed
        meta["source/task_id"] = self.task_id
        self.episodes.append(meta)
        self._episode_stats.append(ep_stats)
        self.total_frames += n

    # ------------------------------------------------------------------ closing

    def close(self, card: str = "") -> None:
        self._data.close()
        for video in self._videos.values():
            video.close()
        meta = self.root / "meta"
        (meta / "episodes" / "chunk-000").mkdir(parents=True, exist_ok=True)
        if self.episodes:
            pq.write_table(
                pa.Table.from_pylist(self.episodes),
                self.root / EPISODES_PATH.format(chunk_index=0, file_index=0),
            )
        _write_tasks(meta / "tasks.parquet", self.tasks)
        videos = {video_key(c) for c in self.cameras}
        merged = {
            f: st.merge([s[f] for s in self._episode_stats])
            for f in self.features
            if self.episodes and f not in videos
        }
        for cam, hist in self._image_hist.items():
            if self.episodes:
                merged[video_key(cam)] = st.histogram_stats(hist, self.total_frames)
        (meta / "stats.json").write_text(json.dumps(st.to_json(merged), indent=2))
        (meta / "info.json").write_text(json.dumps(self.info(), indent=2))
        (self.root / "README.md").write_text(card)

    def info(self) -> dict:
        return {
            "codebase_version": CODEBASE_VERSION,
            "robot_type": self.robot_type,
            "total_episodes": len(self.episodes),
            "total_frames": self.total_frames,
            "total_tasks": len(self.tasks),
            "chunks_size": self.limits.chunks_size,
            "data_files_size_in_mb": self.limits.data_files_size_in_mb,
            "video_files_size_in_mb": self.limits.video_files_size_in_mb,
            "fps": self.fps,
            "splits": {"train": f"0:{len(self.episodes)}"},
            "data_path": DATA_PATH,
            "video_path": VIDEO_PATH if self.cameras else None,
            "features": self.features,
        }

    def _features(self) -> dict[str, dict]:
        f: dict[str, dict] = {
            "observation.state": {
                "dtype": "float32",
                "shape": [len(STATE_NAMES)],
                "names": list(STATE_NAMES),
            },
            "action": {
                "dtype": "float32",
                "shape": [len(ACTION_NAMES)],
                "names": list(ACTION_NAMES),
            },
        }
        for cam, (w, h) in self.cameras.items():
            f[video_key(cam)] = {
                "dtype": "video",
                "shape": [h, w, 3],
                "names": ["height", "width", "channels"],
                "info": {
                    "video.height": h,
                    "video.width": w,
                    "video.codec": "h264",
                    "video.pix_fmt": "yuv420p",
                    "video.is_depth_map": False,
                    "video.fps": self.fps,
                    "video.channels": 3,
                    "has_audio": False,
                },
            }
        f["timestamp"] = {"dtype": "float32", "shape": [1], "names": None}
        f["session_time_s"] = {"dtype": "float64", "shape": [1], "names": None}
        for k in ("frame_index", "episode_index", "index", "task_index"):
            f[k] = {"dtype": "int64", "shape": [1], "names": None}
        f["next.done"] = {"dtype": "bool", "shape": [1], "names": None}
        return f


class LeRobotExport:
    """`learn.export`'s adapter: episode parts, in order, into one `LeRobotWriter`."""

    def __init__(self, out: Path, options, sizes: dict[str, tuple[int, int]], task: str):
        self.task = task
        self.options = options
        self.writer = LeRobotWriter(
            out, options.fps, sizes, task_id=options.task_id, limits=options.lerobot_limits
        )
        self.onboard_hz: dict[str, float] = {}  # the onboard streams exported, their rates

    def add(self, part: EpisodePart) -> None:
        self.writer.add_episode(part, self.task)
        if part.onboard is not None and len(part):
            place_series(self.writer.root, len(self.writer.episodes) - 1, part.onboard)
            self.onboard_hz.update(part.onboard.rates_hz)

    def close(self, summary) -> None:
        card = dataset_card(self.writer, self.options, summary, self.task)
        self.writer.close(card + lerobot_card_section(self.onboard_hz))


def dataset_card(w: LeRobotWriter, options, summary, task: str) -> str:
    """README.md in the shape of LeRobot's cards (YAML front matter, then the layout)."""
    state = "\n".join(f"| {i} | `{n}` |" for i, n in enumerate(STATE_NAMES))
    cams = ", ".join(f"`{video_key(c)}` ({wh[0]}x{wh[1]})" for c, wh in w.cameras.items())
    return f"""---
license: cc-by-4.0
task_categories:
- robotics
tags:
- LeRobot
- fpv-station
- quadcopter
configs:
- config_name: default
  data_files: data/*/*.parquet
---

# {options.dataset_id}

Human-style FPV flight demonstrations of an F450 quadcopter, exported by fpv-station from
{summary.recordings} recording(s): {len(w.episodes)} episodes (one per flight: arming to
disarming), {w.total_frames} frames at {w.fps} fps. Cameras: {cams or "none"}.

- Task {options.task_id}: {task}
- `observation.state`: the state vector of the twin's Gymnasium env (`TwinEnv`), so a
  policy trained here flies `TwinEnv(task={options.task_id})` directly.
- `action`: the pilot's sticks (roll, pitch, yaw, throttle) in [-1, 1], from the RC
  channels; throttle -1 is full descent, 0 holds altitude (Position mode).
- `timestamp`: seconds since the episode's first frame; `session_time_s`: the same
  instant on the recording's session clock.

Load it with `LeRobotDataset("{options.dataset_id}", root=DIR)`.

| index | `observation.state` element |
| ---: | --- |
{state}

[meta/info.json](meta/info.json) holds the features, shapes and path templates.
"""


class _DataFiles:
    """data/chunk-CCC/file-FFF.parquet, one episode per row group, rolled over by
    LeRobot's rule (module docstring)."""

    def __init__(self, root: Path, schema: pa.Schema, limits: FileLimits) -> None:
        self.root, self.schema, self.limits = root, schema, limits
        self.index = (0, 0)
        self.writer: pq.ParquetWriter | None = None
        self.rows = 0  # in the current file

    def _path(self) -> Path:
        return self.root / DATA_PATH.format(chunk_index=self.index[0], file_index=self.index[1])

    def write(self, table: pa.Table) -> tuple[int, int]:
        if self.writer is not None:
            size_mb = _size_mb(self._path())
            if size_mb + size_mb / self.rows * table.num_rows >= self.limits.data_files_size_in_mb:
                self.writer.close()
                self.writer = None
                self.index = next_file(*self.index, self.limits.chunks_size)
        if self.writer is None:
            path = self._path()
            path.parent.mkdir(parents=True, exist_ok=True)
            self.writer = pq.ParquetWriter(path, self.schema, compression="snappy")
            self.rows = 0
        self.writer.write_table(table)
        self.rows += table.num_rows
        return self.index

    def close(self) -> None:
        if self.writer is None:  # no episode: an empty file, as the layout expects one
            path = self._path()
            path.parent.mkdir(parents=True, exist_ok=True)
            self.writer = pq.ParquetWriter(path, self.schema, compression="snappy")
        self.writer.close()


class _VideoFiles:
    """videos/KEY/chunk-CCC/file-FFF.mp4 of one camera: each episode's part file's
    packets appended as they are (timestamps shifted by the frames already in the file),
    rolled over by LeRobot's rule (module docstring)."""

    def __init__(self, root: Path, camera: str, fps: int, limits: FileLimits) -> None:
        self.root, self.camera, self.fps, self.limits = root, camera, fps, limits
        self.index = (0, 0)
        self.container: av.container.OutputContainer | None = None
        self.stream: av.VideoStream | None = None
        self.frames = 0  # in the current file
        self.bytes = 0  # packet bytes in the current file

    def append(self, part: Path, frames: int) -> tuple[int, int, int]:
        """Move a part file's frames in; returns (chunk, file, frames before them)."""
        part_mb = os.path.getsize(part) / MB
        limit = self.limits.video_files_size_in_mb
        if self.container is not None and self.bytes / MB + part_mb >= limit:
            self.close()
            self.index = next_file(*self.index, self.limits.chunks_size)
        with av.open(str(part)) as source:
            src = source.streams.video[0]
            if src.time_base is None:
                raise ValueError(f"{part}: its video stream has no time base")
            container, stream = self.container, self.stream
            if container is None or stream is None:
                path = self.root / VIDEO_PATH.format(
                    video_key=video_key(self.camera),
                    chunk_index=self.index[0],
                    file_index=self.index[1],
                )
                path.parent.mkdir(parents=True, exist_ok=True)
                container = self.container = av.open(str(path), mode="w")
                stream = self.stream = container.add_stream_from_template(src)
                self.frames = self.bytes = 0
            start = self.frames
            shift = int(round(Fraction(start, self.fps) / src.time_base))
            for packet in source.demux(src):
                if packet.size == 0:  # the demuxer's end-of-stream marker
                    continue
                if packet.pts is None or packet.dts is None:
                    raise ValueError(f"{part}: a video packet without a timestamp")
                packet.pts += shift
                packet.dts += shift
                packet.stream = stream
                self.bytes += packet.size
                container.mux(packet)
        os.unlink(part)
        self.frames += frames
        return (*self.index, start)

    def close(self) -> None:
        if self.container is not None:
            self.container.close()
            self.container = None


def _size_mb(path: Path) -> float:
    return os.path.getsize(path) / MB


def _fixed_list(a: np.ndarray) -> pa.FixedSizeListArray:
    a = np.ascontiguousarray(a, dtype=np.float32)
    return pa.FixedSizeListArray.from_arrays(pa.array(a.ravel()), a.shape[1])


def _write_tasks(path: Path, tasks: dict[str, int]) -> None:
    """tasks.parquet as pandas writes a frame indexed by "task" (LeRobot reads it with
    `pd.read_parquet` and looks tasks up by that index)."""
    names = list(tasks)
    table = pa.table(
        {
            "task_index": pa.array([tasks[t] for t in names], pa.int64()),
            "task": pa.array(names, pa.string()),
        }
    )
    pandas_meta = {
        "index_columns": ["task"],
        "column_indexes": [
            {
                "name": None,
                "field_name": None,
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": {"encoding": "UTF-8"},
            }
        ],
        "columns": [
            {
                "name": "task_index",
                "field_name": "task_index",
                "pandas_type": "int64",
                "numpy_type": "int64",
                "metadata": None,
            },
            {
                "name": "task",
                "field_name": "task",
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": None,
            },
        ],
        "creator": {"library": "pyarrow", "version": pa.__version__},
        "pandas_version": "2.2.0",
    }
    table = table.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()})
    pq.write_table(table, path)
