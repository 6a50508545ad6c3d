"""`fpv-station export` on a recorded twin flight (the scripted pilot flown by `demos`: real
MAVLink over UDP, the recorder's writer, both cameras) and on a bare tlog with several
sorties. Expected values are computed here from the session's own files (csv module,
pymavlink, PyAV), not through the exporter's code."""

from __future__ import annotations

import csv
import json
import math
import os
from dataclasses import replace
from pathlib import Path

import av
import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

from fpv_station.learn.demos import DemoConfig
from fpv_station.learn.episodes import ChannelMap
from fpv_station.learn.export import ExportOptions, export_recordings, recorded_task_id
from fpv_station.learn.formats import FileLimits
from fpv_station.server.cli import main as cli_main
from tests import synthetic as syn
from tests.demo_flights import shared_demo
from tests.known_flights import three_sorties
from tests.recording_fakes import as_format_1, recorded_frames

FPS = 10
# The module's fixtures fly a twin demo with both cameras (once for the whole run,
# `shared_demo`) and export it (~15 s alone); on a shared machine the first test to use
# them can take minutes.
pytestmark = pytest.mark.timeout(600)


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    return shared_demo(tmp_path_factory, 3, DemoConfig(task_id=1, cameras=True))


@pytest.fixture(scope="module")
def rows(session) -> list[dict]:
    with open(session / "telemetry.csv", newline="") as f:
        return list(csv.DictReader(f))


def _f(v: str) -> float:
    return float(v) if v not in ("", None) else math.nan


def _armed_span(rows) -> tuple[float, float]:
    """Session times of the first and last armed rows (the demo has one flight)."""
    armed = [r for r in rows if r["heartbeat.armed"] == "1"]
    return float(armed[0]["t_s"]), float(armed[-1]["t_s"])


@pytest.fixture(scope="module")
def lerobot(session, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("lerobot")
    s = export_recordings([session], "lerobot", out, ExportOptions(task_id=1, fps=FPS))
    assert (s.episodes, s.recordings) == (1, 1)
    return out


def test_lerobot_layout_and_schema_match_info(lerobot):
    info = json.loads((lerobot / "meta/info.json").read_text())
    assert info["codebase_version"] == "v3.0" and info["fps"] == FPS
    for f in (
        "meta/stats.json",
        "meta/tasks.parquet",
        "meta/episodes/chunk-000/file-000.parquet",
        "data/chunk-000/file-000.parquet",
        "videos/observation.images.front/chunk-000/file-000.mp4",
        "videos/observation.images.bottom/chunk-000/file-000.mp4",
        "README.md",
    ):
        assert (lerobot / f).is_file(), f
    assert (
        info["data_path"].format(chunk_index=0, file_index=0) == "data/chunk-000/file-000.parquet"
    )
    schema = pq.read_schema(lerobot / "data/chunk-000/file-000.parquet")
    features = info["features"]
    tabular = {k: f for k, f in features.items() if f["dtype"] != "video"}
    assert set(schema.names) == set(tabular)
    for name, ft in tabular.items():
        t = schema.field(name).type
        if ft["shape"] == [1]:
            assert str(t) == {"float32": "float", "float64": "double"}.get(ft["dtype"], ft["dtype"])
        else:
            assert t.list_size == ft["shape"][0] and str(t.value_type) == "float"
            assert len(ft["names"]) == ft["shape"][0]
    assert features["observation.state"]["shape"] == [18]
    assert features["action"]["names"] == ["roll", "pitch", "yaw", "throttle"]
    # tasks.parquet reads back (pandas) indexed by the task text, as LeRobot looks it up.
    tasks = pq.read_table(lerobot / "meta/tasks.parquet")
    pandas_meta = json.loads(tasks.schema.metadata[b"pandas"])
    assert pandas_meta["index_columns"] == ["task"]
    assert tasks.column("task_index").to_pylist() == [0]
    assert "Take off" in tasks.column("task").to_pylist()[0]


def test_lerobot_rows_are_fps_times_duration_on_the_session_clock(lerobot, rows):
    arm, disarm = _armed_span(rows)
    data = pq.read_table(lerobot / "data/chunk-000/file-000.parquet").to_pydict()
    n = len(data["index"])
    assert n == math.floor((disarm - arm) * FPS + 1e-6) + 1
    assert data["session_time_s"][0] == pytest.approx(arm)
    assert np.allclose(np.diff(data["session_time_s"]), 1 / FPS)
    assert np.allclose(data["timestamp"], np.arange(n) / FPS, atol=1e-5)
    assert data["frame_index"] == list(range(n)) and data["index"] == list(range(n))
    assert set(data["episode_index"]) == {0} and set(data["task_index"]) == {0}
    assert data["next.done"][-1] and not any(data["next.done"][:-1])
    ep = pq.read_table(lerobot / "meta/episodes/chunk-000/file-000.parquet").to_pylist()[0]
    assert (ep["dataset_from_index"], ep["dataset_to_index"], ep["length"]) == (0, n, n)
    assert ep["videos/observation.images.front/to_timestamp"] == pytest.approx(n / FPS)


def test_lerobot_actions_are_the_recorded_sticks(lerobot, rows):
    data = pq.read_table(lerobot / "data/chunk-000/file-000.parquet").to_pydict()
    t_rows = np.array([float(r["t_s"]) for r in rows])
    pwm = np.array([[_f(r[f"rc.pwm_us.{c}"]) for c in range(4)] for r in rows])
    moved = 0
    for t, action in zip(data["session_time_s"], data["action"]):
        r = int(np.searchsorted(t_rows, t + 1e-9, side="right") - 1)
        roll, pitch, throttle, yaw = pwm[r]  # the twin's RC map: AETR
        want = [
            (roll - 1500) / 500,
            (pitch - 1500) / 500,
            (yaw - 1500) / 500,
            (throttle - 1500) / 500,
        ]
        assert np.allclose(action, want, atol=1e-6), (t, action, want)
        moved += abs(want[1]) > 0.05
    assert moved > 5  # the pilot did move the sticks: the comparison is not all zeros


def test_lerobot_state_follows_the_flight(lerobot, rows):
    data = pq.read_table(lerobot / "data/chunk-000/file-000.parquet").to_pydict()
    state = np.array(data["observation.state"])
    height = state[:, 17]
    assert height.max() == pytest.approx(4.0, abs=0.4)  # the hover at 4 m over the pad
    assert np.abs(state[:, 0:2]).max() < 1.5  # task 1: the target is the start pad
    # Armed, and still low: the pilot climbs at once, and the armed HEARTBEAT (1 Hz) can
    # reach the station a few centimetres into the climb.
    assert state[0, 14] == 1.0 and height[0] < 0.5
    assert state[-1, 14] == 1.0 and state[-1, 15] == 1.0  # landed, not yet disarmed
    assert (state[:, 15] == 0).any()  # airborne at some point
    assert np.allclose(state[:, 8] ** 2 + state[:, 9] ** 2, 1.0, atol=1e-5)


def test_lerobot_videos_decode_to_the_declared_frames(lerobot, session):
    info = json.loads((lerobot / "meta/info.json").read_text())
    data = pq.read_table(lerobot / "data/chunk-000/file-000.parquet").to_pydict()
    for cam in ("front", "bottom"):
        key = f"observation.images.{cam}"
        h, w, _ = info["features"][key]["shape"]
        path = lerobot / info["video_path"].format(video_key=key, chunk_index=0, file_index=0)
        with av.open(str(path)) as c:
            frames = [f.to_ndarray(format="bgr24") for f in c.decode(video=0)]
        assert len(frames) == info["total_frames"]
        assert frames[0].shape == (h, w, 3)
        # Frame k is the JPEG recorded at or before its instant, not merely some frame.
        with open(session / cam / "frames.csv", newline="") as f:
            recorded = list(csv.DictReader(f))
        t_rec = np.array([float(r["t_s"]) for r in recorded])
        on_disk = recorded_frames(session, cam)

        def image(r: dict, on_disk: dict[str, bytes] = on_disk) -> np.ndarray:
            bgr = cv2.imdecode(np.frombuffer(on_disk[r["file"]], np.uint8), cv2.IMREAD_COLOR)
            assert bgr is not None, r["file"]
            return bgr

        for k in (5, len(frames) // 2, len(frames) - 3):
            j = int(np.searchsorted(t_rec, data["session_time_s"][k] + 1e-9, side="right") - 1)
            jpeg = image(recorded[j])
            far = image(recorded[(j + len(recorded) // 2) % len(recorded)])
            err = np.abs(frames[k].astype(int) - jpeg.astype(int)).mean()
            assert err < 6.0, (cam, k, err)
            if cam == "front":  # the bottom view of grass can look alike at any time
                assert err < np.abs(frames[k].astype(int) - far.astype(int)).mean()


def test_lerobot_stats_agree_with_the_data(lerobot):
    stats = json.loads((lerobot / "meta/stats.json").read_text())
    data = pq.read_table(lerobot / "data/chunk-000/file-000.parquet").to_pydict()
    for key in ("observation.state", "action"):
        v = np.array(data[key], dtype=np.float64)
        s = stats[key]
        assert np.allclose(s["mean"], v.mean(0), atol=1e-6)
        assert np.allclose(s["std"], v.std(0), atol=1e-6)
        assert np.allclose(s["min"], v.min(0)) and np.allclose(s["max"], v.max(0))
        assert np.allclose(s["q50"], np.quantile(v, 0.5, axis=0), atol=1e-6)
        assert s["count"] == [len(v)]
    img = stats["observation.images.front"]
    assert np.array(img["mean"]).shape == (3, 1, 1)
    assert all(0 <= m <= 1 for m in np.ravel(img["mean"]))


def test_mcap_holds_every_frame_row_and_packet_with_foxglove_schemas(session, rows, tmp_path):
    from mcap.reader import make_reader
    from pymavlink import mavutil

    out = tmp_path / "mcap"
    s = export_recordings([session], "mcap", out, ExportOptions(task_id=1))
    (path,) = sorted(out.glob("*.mcap"))
    arm, disarm = _armed_span(rows)
    meta = json.loads((session / "session.json").read_text())
    wall0 = meta["start_wall"]
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        counts = {
            summary.channels[cid].topic: n
            for cid, n in summary.statistics.channel_message_counts.items()
        }
        schemas = {
            summary.channels[cid].topic: summary.schemas[summary.channels[cid].schema_id].name
            for cid in summary.channels
        }
        first_image = None
        for _schema, _channel, message in reader.iter_messages(topics=["/front/image/compressed"]):
            first_image = message.data  # a protobuf foxglove.CompressedImage
            break
    n_rows = sum(arm <= float(r["t_s"]) <= disarm for r in rows)
    for cam in ("front", "bottom"):
        with open(session / cam / "frames.csv", newline="") as f:
            frames = [r for r in csv.DictReader(f) if arm <= float(r["t_s"]) <= disarm]
        assert counts[f"/{cam}/image/compressed"] == len(frames)
        assert schemas[f"/{cam}/image/compressed"] == "foxglove.CompressedImage"
        if cam == "front":
            first_file = recorded_frames(session, cam)[frames[0]["file"]]
    assert counts["/telemetry"] == counts["/gps"] == counts["/pose"] == counts["/tf"] == n_rows
    assert schemas["/gps"] == "foxglove.LocationFix"
    assert schemas["/pose"] == "foxglove.PoseInFrame"
    assert schemas["/tf"] == "foxglove.FrameTransform"
    # Raw MAVLink: every tlog packet received between arming and disarming.
    log = mavutil.mavlink_connection(str(session / "mavlink.tlog"))
    packets = 0
    while (m := log.recv_match()) is not None:
        packets += arm - 1e-6 <= m._timestamp - wall0 <= disarm + 1e-6
    assert counts["/mavlink"] == packets > 100
    # The recorded JPEG, byte for byte, inside the message: no re-encode.
    assert first_file.startswith(b"\xff\xd8") and first_file in first_image
    assert len(first_image) - len(first_file) < 64
    assert s.camera_frames == counts["/front/image/compressed"] + counts["/bottom/image/compressed"]


def test_minari_dataset_loads_and_recovers_the_twin(session, tmp_path, monkeypatch):
    import minari

    out = tmp_path / "minari"
    export_recordings([session, session], "minari", out, ExportOptions(task_id=1, fps=FPS))
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    ds = minari.load_dataset("fpv-station/twin-task1/demos-v0")
    assert ds.total_episodes == 2
    ep = next(ds.iterate_episodes())
    assert ep.observations.shape[1] == 18
    assert ep.actions.shape == (ep.observations.shape[0] - 1, 4)
    assert ep.terminations[-1] and not ep.truncations[-1]  # landed
    assert ep.rewards[-1] > 9  # the env's +10 for landing on the pad
    # Progress steps are small, but for the one where the held hover (10 s within 0.3 m of
    # 4 m) moves the env's target from 4 m over the pad down to the pad: about -4.
    big = np.flatnonzero(abs(ep.rewards[:-1]) > 1.0)
    assert big.size == 1 and ep.rewards[big[0]] == pytest.approx(-4.0, abs=0.6)
    assert ep.observations[big[0], 17] == pytest.approx(4.0, abs=0.3)
    env = ds.recover_environment()
    assert env.unwrapped.task.id == 1 and env.unwrapped.control_hz == FPS
    obs, _ = env.reset(seed=0)
    assert obs.shape == ds.observation_space.shape
    obs, reward, *_ = env.step(np.zeros(4, np.float32))
    assert np.isfinite(reward)
    assert os.environ["MINARI_DATASETS_PATH"] == str(out)


def test_a_bare_tlog_with_several_sorties_gives_one_episode_per_flight(tmp_path):
    tlog = syn.write_tlog(three_sorties(), tmp_path / "sorties.tlog")
    out = tmp_path / "lerobot"
    s = export_recordings([tlog], "lerobot", out, ExportOptions(task_id=2, fps=5))
    assert s.episodes == 3  # the motor test and the post-disarm tail are no episodes
    eps = pq.read_table(out / "meta/episodes/chunk-000/file-000.parquet").to_pydict()
    assert eps["length"] == [math.floor(d * 5 + 1e-6) + 1 for d in (19.9, 17.9, 11.9)]
    info = json.loads((out / "meta/info.json").read_text())
    assert info["video_path"] is None and not (out / "videos").exists()


def test_channel_maps():
    pwm = np.full((1, 18), 1500.0)
    pwm[0, :4] = [2000, 1000, 1250, 1750]
    assert ChannelMap().sticks(pwm).tolist() == [[1.0, -1.0, 0.5, -0.5]]
    assert ChannelMap.parse("TAER").sticks(pwm).tolist() == [[-1.0, -0.5, 0.5, 1.0]]
    assert ChannelMap.parse("roll=1,pitch=-2,throttle=3,yaw=4").sticks(pwm)[0, 1] == 1.0
    unused = np.zeros((1, 18))
    assert ChannelMap().sticks(unused).tolist() == [[0.0, 0.0, 0.0, 0.0]]
    with pytest.raises(ValueError):
        ChannelMap.parse("roll=1,pitch=2")
    with pytest.raises(ValueError):
        ChannelMap.parse("roll=1,pitch=2,throttle=3,yaw=40")


def test_cli_export_and_its_errors(session, tmp_path, capsys):
    out = tmp_path / "cli"
    argv = ["export", str(session), "--format", "mcap", "--out", str(out), "--no-progress"]
    assert cli_main(argv) == 0
    assert "mcap: 1 episodes" in capsys.readouterr().out
    assert len(list(out.glob("*.mcap"))) == 1
    assert cli_main([*argv, "--cameras", "left"]) == 1
    assert "no frames of camera left" in capsys.readouterr().err
    assert cli_main([*argv, "--channel-map", "XYZ"]) == 2
    assert cli_main([*argv[:2], str(tmp_path / "missing"), *argv[2:]]) == 1
    assert "does not exist" in capsys.readouterr().err
    assert cli_main([*argv, "--task", "9"]) == 1
    assert cli_main([*argv, "--video-files-size-mb", "0"]) == 2
    assert "video_files_size_in_mb must be positive" in capsys.readouterr().err


def test_telemetry_read_in_small_blocks_is_the_same(session, monkeypatch):
    from fpv_station.analysis import recording
    from fpv_station.learn.episodes import COLUMNS

    with recording.open_recording(session, COLUMNS) as whole:
        monkeypatch.setattr(recording, "CSV_BLOCK_BYTES", 1000)  # rows cut across blocks
        with recording.open_recording(session, COLUMNS) as blocks:
            assert np.array_equal(whole.t_s, blocks.t_s)
            for name, col in whole.columns.items():
                assert np.array_equal(col, blocks.columns[name], equal_nan=True), name
    assert whole.t_s.size > 500


def _lerobot_tables(root: Path, cache: Path):
    """info.json, and the episodes and the rows of every file in sorted order as LeRobot
    loads them (`load_nested_dataset`): Hugging Face `datasets`, the rows with the
    features LeRobot derives from info.json."""
    import datasets

    info = json.loads((root / "meta/info.json").read_text())
    features = {}
    for key, ft in info["features"].items():
        if ft["dtype"] == "video":
            continue
        if tuple(ft["shape"]) == (1,):
            features[key] = datasets.Value(dtype=ft["dtype"])
        else:
            features[key] = datasets.Sequence(
                length=ft["shape"][0], feature=datasets.Value(dtype=ft["dtype"])
            )
    episodes = datasets.Dataset.from_parquet(
        [str(p) for p in sorted((root / "meta/episodes").glob("*/*.parquet"))],
        cache_dir=str(cache),  # datasets caches arrow copies: not in the home folder
    )
    rows = datasets.Dataset.from_parquet(
        [str(p) for p in sorted((root / "data").glob("*/*.parquet"))],
        features=datasets.Features(features),
        cache_dir=str(cache),
    ).with_format("numpy")
    return info, episodes, rows


def test_lerobot_reads_back_the_way_lerobot_reads_it(lerobot, tmp_path):
    """LeRobot's v3.0 reader, step by step, without LeRobot (it pulls in PyTorch): info
    with tuple shapes, tasks through pandas indexed by the task text, episodes and rows
    through Hugging Face `datasets` with the features LeRobot derives from info.json, and
    video frames found at `from_timestamp + timestamp` within LeRobot's 1e-4 s."""
    import pandas as pd

    info, episodes, rows = _lerobot_tables(lerobot, tmp_path)
    tasks = pd.read_parquet(lerobot / "meta/tasks.parquet")
    tasks.index.name = "task"
    assert len(rows) == info["total_frames"] and len(episodes) == info["total_episodes"]
    ep = episodes[0]
    assert int(tasks.loc[ep["tasks"][0]].task_index) == 0
    part = rows[ep["dataset_from_index"] : ep["dataset_to_index"]]
    assert part["observation.state"].shape == (ep["length"], 18)
    key = "observation.images.front"
    path = lerobot / info["video_path"].format(
        video_key=key,
        chunk_index=ep[f"videos/{key}/chunk_index"],
        file_index=ep[f"videos/{key}/file_index"],
    )
    ts = part["timestamp"]
    query = [ep[f"videos/{key}/from_timestamp"] + float(ts[k]) for k in (0, len(ts) // 2, -1)]
    found = []
    with av.open(str(path)) as c:
        s = c.streams.video[0]
        c.seek(int(query[0] / s.time_base), stream=s, backward=True, any_frame=False)
        for frame in c.decode(s):
            t = float(frame.pts * s.time_base)
            found += [q for q in query if abs(t - q) < 1e-4]
            if t > query[-1]:
                break
    assert found == query


def _mcap_images(path: Path) -> dict[str, list[bytes]]:
    from mcap.reader import make_reader

    out: dict[str, list[bytes]] = {}
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages():
            if channel.topic.endswith("/image/compressed"):
                out.setdefault(channel.topic, []).append(message.data)
    return out


def test_a_format_1_session_exports_the_same_frames(session, tmp_path):
    """A session recorded before the frame pack (a JPEG file per frame) still exports:
    the same images, byte for byte, as the packed session it was made from."""
    import shutil

    old = tmp_path / "v1" / session.name
    shutil.copytree(session, old)
    as_format_1(old)
    assert not list(old.glob("*/frames.mjpeg")) and len(list(old.glob("front/*.jpg"))) > 10
    export_recordings([session], "mcap", tmp_path / "v2out", ExportOptions(task_id=1))
    export_recordings([old], "mcap", tmp_path / "v1out", ExportOptions(task_id=1))
    (v2,), (v1,) = (
        sorted((tmp_path / "v2out").glob("*.mcap")),
        sorted((tmp_path / "v1out").glob("*.mcap")),
    )
    images = _mcap_images(v2)
    assert set(images) == {"/front/image/compressed", "/bottom/image/compressed"}
    assert all(len(v) > 10 for v in images.values())
    assert _mcap_images(v1) == images


def test_a_session_zip_exports_like_its_folder(session, tmp_path):
    import shutil
    import tempfile

    archive = shutil.make_archive(str(tmp_path / session.name), "zip", session.parent, session.name)
    unpacked = lambda: set(Path(tempfile.gettempdir()).glob("fpv-export-*"))  # noqa: E731
    before = unpacked()
    a = export_recordings([session], "minari", tmp_path / "a", ExportOptions(task_id=1))
    b = export_recordings([Path(archive)], "minari", tmp_path / "b", ExportOptions(task_id=1))
    assert (a.episodes, a.frames) == (b.episodes, b.frames) == (1, a.frames)
    assert unpacked() == before  # the unpacked copy is gone


def test_an_episode_carries_the_task_its_session_was_flown_for(session, tmp_path):
    """The pilot chose task 2 on the page (session.json `task`): with no --task the export
    labels the episode with it; sessions of two tasks are refused together."""
    import shutil

    from fpv_station.analysis.recording import RecordingError

    def flown_for(task_id: int, name: str) -> Path:
        copy = tmp_path / f"{session.name[:-4]}_t{task_id}"
        shutil.copytree(session, copy)
        meta = json.loads((copy / "session.json").read_text())
        meta["task"] = {"id": task_id, "name": name}
        (copy / "session.json").write_text(json.dumps(meta))
        return copy

    a_to_b = flown_for(2, "A to B")
    # Zipped (as the sessions page downloads it), the task is read without unpacking.
    zipped = Path(shutil.make_archive(str(tmp_path / "a_to_b"), "zip", a_to_b.parent, a_to_b.name))
    assert recorded_task_id([zipped]) == 2 and recorded_task_id([session]) == 1
    out = tmp_path / "ds"
    s = export_recordings([a_to_b], "lerobot", out, ExportOptions(fps=FPS, cameras=()))
    assert s.episodes == 1
    tasks = pq.read_table(out / "meta/tasks.parquet").column("task").to_pylist()
    assert len(tasks) == 1 and tasks[0].startswith("A to B")
    with pytest.raises(RecordingError, match=r"tasks \[1, 2\]"):
        export_recordings(
            [a_to_b, flown_for(1, "Take off, hover, land")],
            "lerobot",
            tmp_path / "mixed",
            ExportOptions(fps=FPS, cameras=()),
        )


def test_a_session_of_unknown_task_is_refused_unless_the_task_is_given(session, tmp_path, capsys):
    """A demonstration records the task it flew (as a session recorded on the pilot page);
    one whose session.json says no task is never exported under a guessed one."""
    import shutil

    meta = json.loads((session / "session.json").read_text())
    assert meta["task"]["id"] == 1 and meta["task"]["end_pad"]  # written by the recorder
    assert meta["trigger"] == "demos" and meta["status"] == "complete"
    untold = tmp_path / session.name
    shutil.copytree(session, untold)
    meta.pop("task")
    (untold / "session.json").write_text(json.dumps(meta))

    argv = ["export", str(untold), "--format", "mcap", "--no-progress", "--cameras", "none"]
    assert cli_main([*argv, "--out", str(tmp_path / "guessed")]) == 1
    assert "no task recorded" in capsys.readouterr().err
    assert not (tmp_path / "guessed").exists()
    assert cli_main([*argv, "--out", str(tmp_path / "told"), "--task", "2"]) == 0
    assert "mcap: 1 episodes" in capsys.readouterr().out


@pytest.fixture(scope="module")
def three(session, tmp_path_factory) -> list[Path]:
    """The demo session and two copies under other session ids: three recordings whose
    episodes differ in their source (so an export in another order shows)."""
    import shutil

    out = [session]
    for name in ("b", "c"):
        copy = tmp_path_factory.mktemp("three") / f"{session.name}{name}"
        shutil.copytree(session, copy)
        meta = json.loads((copy / "session.json").read_text())
        meta["id"] = copy.name
        (copy / "session.json").write_text(json.dumps(meta))
        out.append(copy)
    return out


@pytest.fixture(scope="module")
def small(three, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("small")
    opts = ExportOptions(task_id=1, fps=FPS, image_size=(160, 120))
    export_recordings(three, "lerobot", out, opts)
    return out


def _all_frames(session: Path, cam: str, t_s: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(n, H, W, 3) RGB: for every dataset instant, the JPEG recorded at or before it,
    decoded and scaled to `size`, straight from the session's files."""
    with open(session / cam / "frames.csv", newline="") as f:
        recorded = list(csv.DictReader(f))
    t_rec = np.array([float(r["t_s"]) for r in recorded])
    on_disk = recorded_frames(session, cam)
    decoded: dict[int, np.ndarray] = {}  # a recorded frame's picture, decoded once
    out = []
    for t in t_s:
        j = max(int(np.searchsorted(t_rec, t + 1e-9, side="right") - 1), 0)
        if j not in decoded:
            bgr = cv2.imdecode(np.frombuffer(on_disk[recorded[j]["file"]], np.uint8), 1)
            assert bgr is not None, recorded[j]["file"]
            decoded[j] = cv2.resize(bgr, size, interpolation=cv2.INTER_AREA)[..., ::-1]
        out.append(decoded[j])
    return np.stack(out)


def test_image_size_resizes_once_and_image_stats_hold_over_all_frames(small, session):
    """`--image-size 160x120`: the videos are 160x120, and the image stats (dataset and per
    episode) are within 0.01 of the same stats computed over every frame's pixels."""
    info = json.loads((small / "meta/info.json").read_text())
    stats = json.loads((small / "meta/stats.json").read_text())
    data = pq.read_table(small / "data/chunk-000/file-000.parquet").to_pydict()
    episodes = pq.read_table(small / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    t_s = np.array(data["session_time_s"])
    for cam in ("front", "bottom"):
        key = f"observation.images.{cam}"
        assert info["features"][key]["shape"] == [120, 160, 3]
        path = small / info["video_path"].format(video_key=key, chunk_index=0, file_index=0)
        with av.open(str(path)) as c:
            s = c.streams.video[0]
            assert (s.width, s.height) == (160, 120)
            assert sum(1 for _ in c.decode(s)) == info["total_frames"]
        images = _all_frames(session, cam, t_s, (160, 120))
        # In bytes, scaled to [0, 1] after: the same figures (each is linear in the
        # pixels) at an eighth of the memory; the quantiles in one pass.
        px = images.reshape(-1, 3)
        qs = (0.01, 0.1, 0.5, 0.9, 0.99)
        want = {
            "mean": px.mean(0) / 255.0,
            "std": px.std(0) / 255.0,
            "min": px.min(0) / 255.0,
            "max": px.max(0) / 255.0,
            **{
                f"q{round(q * 100):02d}": v / 255.0
                for q, v in zip(qs, np.quantile(px, qs, axis=0), strict=True)
            },
        }
        for name, value in want.items():
            got = np.ravel(stats[key][name])
            assert np.abs(got - value).max() <= 0.01, (cam, name, got, value)
        assert stats[key]["count"] == [info["total_frames"]]
        # Each episode's own stats, over its own frames.
        for ep in episodes:
            part = images[ep["dataset_from_index"] : ep["dataset_to_index"]]
            px = part.reshape(-1, 3)
            got = np.ravel(ep[f"stats/{key}/mean"])
            assert np.abs(got - px.mean(0) / 255.0).max() <= 0.01, (cam, got, px.mean(0) / 255)
            got = np.ravel(ep[f"stats/{key}/q50"])
            assert np.abs(got - np.quantile(px, 0.5, axis=0) / 255.0).max() <= 0.01


def test_image_size_resizes_mcap_images(session, tmp_path, capsys):
    out = tmp_path / "mcap"
    argv = ["export", str(session), "--format", "mcap", "--out", str(out), "--no-progress"]
    assert cli_main([*argv, "--image-size", "160x120"]) == 0
    (path,) = sorted(out.glob("*.mcap"))
    images = _mcap_images(path)
    assert set(images) == {"/front/image/compressed", "/bottom/image/compressed"}
    for topic, frames in images.items():
        start = frames[0].index(b"\xff\xd8")  # the JPEG inside the protobuf message
        bgr = cv2.imdecode(np.frombuffer(frames[0][start:], np.uint8), cv2.IMREAD_COLOR)
        assert bgr is not None and bgr.shape == (120, 160, 3), topic
    capsys.readouterr()
    assert cli_main([*argv, "--image-size", "160by120"]) == 2
    assert "WIDTHxHEIGHT" in capsys.readouterr().err


def _read_like_lerobot(root: Path, cache: Path) -> tuple[dict, list[dict], dict]:
    """LeRobot v3.0's reader steps (`LeRobotDatasetMetadata`, `load_nested_dataset`):
    info; the episodes from every meta/episodes/*/*.parquet; the rows from every
    data/*/*.parquet in sorted order, through Hugging Face `datasets` with the features
    LeRobot derives from info.json; each episode's rows as rows[from:to]; its frames from
    the video file its chunk and file indices name, at `from_timestamp + timestamp`
    within LeRobot's tolerance (1e-4 s). Returns info, the episodes and, per episode and
    camera, the (n, H, W, 3) frames."""

    info, episodes, rows = _lerobot_tables(root, cache)
    episodes = episodes.to_list()
    assert len(rows) == info["total_frames"] and len(episodes) == info["total_episodes"]
    frames: dict = {}
    videos = [k for k, ft in info["features"].items() if ft["dtype"] == "video"]
    for ep in episodes:
        part = rows[ep["dataset_from_index"] : ep["dataset_to_index"]]
        assert len(part["index"]) == ep["length"]
        assert (part["episode_index"] == ep["episode_index"]).all()
        data_file = root / info["data_path"].format(
            chunk_index=ep["data/chunk_index"], file_index=ep["data/file_index"]
        )
        in_file = pq.read_table(data_file, columns=["index"]).column("index").to_pylist()
        assert set(part["index"].tolist()) <= set(in_file)  # its rows are in the file named
        for key in videos:
            path = root / info["video_path"].format(
                video_key=key,
                chunk_index=ep[f"videos/{key}/chunk_index"],
                file_index=ep[f"videos/{key}/file_index"],
            )
            query = [ep[f"videos/{key}/from_timestamp"] + float(t) for t in part["timestamp"]]
            by_time = {}
            with av.open(str(path)) as c:
                s = c.streams.video[0]
                for frame in c.decode(s):
                    assert frame.pts is not None and s.time_base is not None
                    by_time[float(frame.pts * s.time_base)] = frame.to_ndarray(format="rgb24")
            times = np.array(sorted(by_time))
            got = []
            for q in query:
                j = int(np.argmin(np.abs(times - q)))
                assert abs(times[j] - q) < 1e-4, (key, q, times[j])
                got.append(by_time[times[j]])
            assert ep[f"videos/{key}/to_timestamp"] == pytest.approx(query[-1] + 1 / info["fps"])
            frames[(ep["episode_index"], key)] = np.stack(got)
        frames[(ep["episode_index"], "rows")] = part
    return info, episodes, frames


ROLLED = FileLimits(chunks_size=2, data_files_size_in_mb=0.001, video_files_size_in_mb=0.001)


@pytest.fixture(scope="module")
def rolled(three, small, tmp_path_factory) -> Path:
    """The `small` export (three episodes) with LeRobot's file limits lowered: a video
    file holds two episodes (2.5 episodes' bytes), data files roll over at every episode,
    and two files make a chunk. Exported by the command line, whose limit flags these
    are."""
    front = small / "videos/observation.images.front/chunk-000/file-000.mp4"
    per_episode_mb = front.stat().st_size / 3 / 2**20
    out = tmp_path_factory.mktemp("rolled")
    argv = ["export", *map(str, three), "--format", "lerobot", "--out", str(out)]
    argv += ["--task", "1", "--fps", str(FPS), "--image-size", "160x120", "--no-progress"]
    argv += ["--chunks-size", str(ROLLED.chunks_size), "--workers", "1"]
    argv += ["--data-files-size-mb", str(ROLLED.data_files_size_in_mb)]
    argv += ["--video-files-size-mb", repr(2.5 * per_episode_mb)]
    assert cli_main(argv) == 0
    return out


def test_lerobot_files_roll_over_and_read_back_whole(small, rolled, tmp_path):
    """Files roll over at the limits with LeRobot's chunk and file indices, and the
    dataset reads back through LeRobot's reader steps exactly as the one-file export:
    every row, and every frame of every episode from the file its indices name."""
    info, episodes, frames = _read_like_lerobot(rolled, tmp_path / "a")
    _, ref_episodes, ref_frames = _read_like_lerobot(small, tmp_path / "b")
    assert info["chunks_size"] == 2 and info["data_files_size_in_mb"] == 0.001
    where = [
        (
            (e["data/chunk_index"], e["data/file_index"]),
            (
                e["videos/observation.images.front/chunk_index"],
                e["videos/observation.images.front/file_index"],
            ),
            e["videos/observation.images.front/from_timestamp"],
        )
        for e in episodes
    ]
    n0 = episodes[0]["length"]
    assert where == [
        ((0, 0), (0, 0), 0.0),
        ((0, 1), (0, 0), pytest.approx(n0 / FPS)),
        ((1, 0), (0, 1), 0.0),
    ]
    assert sorted(p.relative_to(rolled).as_posix() for p in rolled.glob("data/*/*")) == [
        "data/chunk-000/file-000.parquet",
        "data/chunk-000/file-001.parquet",
        "data/chunk-001/file-000.parquet",
    ]
    for cam in ("front", "bottom"):  # every video file is one the episodes name
        key = f"observation.images.{cam}"
        named = {
            info["video_path"].format(
                video_key=key,
                chunk_index=e[f"videos/{key}/chunk_index"],
                file_index=e[f"videos/{key}/file_index"],
            )
            for e in episodes
        }
        on_disk = {p.relative_to(rolled).as_posix() for p in rolled.glob(f"videos/{key}/*/*")}
        assert on_disk == named and len(named) >= 2 - (cam == "bottom"), cam
    assert not list(rolled.glob(".parts-*"))  # the part files are gone
    assert len(episodes) == len(ref_episodes) == 3
    for k in range(3):
        rows, ref = frames[(k, "rows")], ref_frames[(k, "rows")]
        for col in ("observation.state", "action", "session_time_s", "index", "timestamp"):
            assert np.array_equal(rows[col], ref[col]), col
        for cam in ("front", "bottom"):
            key = f"observation.images.{cam}"
            assert np.array_equal(frames[(k, key)], ref_frames[(k, key)]), (k, cam)
    assert json.loads((rolled / "meta/stats.json").read_text()) == json.loads(
        (small / "meta/stats.json").read_text()
    )


def _tree(root: Path) -> dict[str, bytes]:
    return {
        p.relative_to(root).as_posix(): p.read_bytes()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def test_workers_export_the_same_dataset_as_one_process(three, rolled, tmp_path):
    """Recordings exported by two worker processes, and the results assembled in order:
    the same files, byte for byte, as one process writes (LeRobot with rolled files,
    MCAP); Minari's episodes the same."""
    import minari

    limits = json.loads((rolled / "meta/info.json").read_text())
    opts = ExportOptions(
        task_id=1,
        fps=FPS,
        image_size=(160, 120),
        lerobot_limits=FileLimits(
            limits["chunks_size"], limits["data_files_size_in_mb"], limits["video_files_size_in_mb"]
        ),
        workers=2,
    )
    out = tmp_path / "lerobot2"
    s = export_recordings(three, "lerobot", out, opts)
    assert s.episodes == 3
    assert _tree(out) == _tree(rolled)
    one, two = tmp_path / "mcap1", tmp_path / "mcap2"
    export_recordings(three, "mcap", one, replace(opts, workers=1))
    export_recordings(three, "mcap", two, opts)
    assert len(_tree(one)) == 3 and _tree(one) == _tree(two)
    m1, m2 = tmp_path / "minari1", tmp_path / "minari2"
    export_recordings(three, "minari", m1, replace(opts, workers=1))
    export_recordings(three, "minari", m2, opts)
    eps = []
    for root in (m1, m2):
        os.environ["MINARI_DATASETS_PATH"] = str(root)
        try:
            ds = minari.load_dataset("fpv-station/twin-task1/demos-v0")
            eps.append([(e.observations, e.actions, e.rewards) for e in ds.iterate_episodes()])
        finally:
            os.environ.pop("MINARI_DATASETS_PATH")
    assert len(eps[0]) == 3
    for x, y in zip(*eps):
        assert all(np.array_equal(u, v) for u, v in zip(x, y))


def test_cli_workers_report_a_bad_recording(three, tmp_path, capsys):
    """`--workers 2`: a recording that fails in a worker process stops the export with
    its own message, as it does in one process."""
    import shutil

    broken = tmp_path / f"{three[0].name}x"
    shutil.copytree(three[0], broken)
    shutil.rmtree(broken / "bottom")
    argv = ["export", str(three[0]), str(broken), "--format", "mcap", "--no-progress"]
    assert cli_main([*argv, "--out", str(tmp_path / "out"), "--workers", "2"]) == 1
    assert f"'{broken}' has no frames of camera bottom" in capsys.readouterr().err
    assert cli_main([*argv, "--out", str(tmp_path / "out"), "--workers", "0"]) == 2


def test_ray_exports_the_same_dataset_as_one_process(tmp_path):
    """`--ray local`: the recordings' jobs as tasks on a new local Ray instance (the
    `export-ray` extra; about a minute and 1 GB to start here, so not in CI's install)."""
    pytest.importorskip("ray")
    tlogs = [syn.write_tlog(three_sorties(), tmp_path / f"s{k}.tlog") for k in range(3)]
    opts = ExportOptions(task_id=2, fps=5)
    export_recordings(tlogs, "lerobot", tmp_path / "one", opts)
    s = export_recordings(tlogs, "lerobot", tmp_path / "ray", replace(opts, ray_address="local"))
    assert s.episodes == 9
    assert _tree(tmp_path / "one") == _tree(tmp_path / "ray")
