import io
import zipfile

import httpx
import pytest

from fpv_station.server.app import create_app
from fpv_station.server.settings import load_settings
from tests.helpers import run_uvicorn


def make_app(tmp_path, token=None):
    overrides = {
        "link.source": "none",
        "viser.enabled": False,
        "recording.sessions_dir": str(tmp_path / "sessions"),
        "recording.auto_record_on_arm": False,
        "recording.min_free_mb": 0,
    }
    if token:
        overrides["server.token"] = token
    return create_app(load_settings(environ={}, overrides=overrides))


@pytest.fixture
def server(tmp_path):
    with run_uvicorn(make_app(tmp_path)) as base:
        yield base, tmp_path / "sessions"


def record_session(base: str, seconds: float = 0.5) -> str:
    import time

    r = httpx.post(f"{base}/api/recording/start")
    assert r.status_code == 200 and r.json()["recording"] is True
    sid = r.json()["id"]
    time.sleep(seconds)
    r = httpx.post(f"{base}/api/recording/stop")
    assert r.status_code == 200 and r.json()["recording"] is False
    assert r.json()["last_stop"]["id"] == sid
    return sid


def test_streamed_zip_unzips_to_the_same_bytes(server):
    base, root = server
    sid = record_session(base)
    # Frames as written by the recorder (the test app has no camera): add real files.
    (root / sid / "front").mkdir(exist_ok=True)
    payloads = {f"front/{i:08d}.jpg": bytes([i % 256]) * (50_000 + i) for i in range(1, 40)}
    for rel, data in payloads.items():
        (root / sid / rel).write_bytes(data)
    with httpx.stream("GET", f"{base}/api/sessions/{sid}/download") as r:
        assert r.status_code == 200 and r.headers["content-type"] == "application/zip"
        assert "content-length" not in r.headers  # streamed, not built first
        chunks = list(r.iter_bytes())
    assert len(chunks) > 1
    zf = zipfile.ZipFile(io.BytesIO(b"".join(chunks)))
    assert zf.testzip() is None
    names = set(zf.namelist())
    on_disk = {p.relative_to(root).as_posix() for p in (root / sid).rglob("*") if p.is_file()}
    assert names == on_disk
    for name in names:
        assert zf.read(name) == (root / name).read_bytes(), name


@pytest.fixture(scope="module")
def camera_server(tmp_path_factory):
    """A station whose two cameras play JPEG folders: its sessions hold real frames."""
    from tests.helpers import station_settings
    from tests.video_fixtures import write_images

    root = tmp_path_factory.mktemp("cams")
    settings = station_settings(
        "none",
        root / "sessions",
        **{
            f"cameras.{cam}.spec": f"folder:{write_images(root / cam, 6, (320, 240), '.jpg')}"
            for cam in ("front", "bottom")
        },
    )
    with run_uvicorn(create_app(settings)) as base:
        yield base, root / "sessions"


def frame_rows(folder, cam: str) -> list[dict[str, str]]:
    import csv

    with open(folder / cam / "frames.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_frames_are_served_byte_for_byte_out_of_the_pack(camera_server):
    """Session format 2: no file per frame; `front/00000042.jpg` (the name frames.csv and
    telemetry.csv give) is served as image/jpeg from frames.mjpeg at the row's offset;
    the detail counts the frames from frames.csv; the zip stores the pack uncompressed."""
    base, root = camera_server
    sid = record_session(base, 1.0)
    folder = root / sid
    assert not list(folder.rglob("*.jpg"))
    detail = httpx.get(f"{base}/api/sessions/{sid}").json()
    rows = {cam: frame_rows(folder, cam) for cam in ("front", "bottom")}
    assert detail["frame_files"] == {cam: len(r) for cam, r in rows.items()}
    assert all(len(r) >= 5 for r in rows.values())
    assert {"front/frames.mjpeg", "bottom/frames.mjpeg", "front/frames.csv"} <= set(detail["files"])
    for cam, listed in rows.items():
        pack = (folder / cam / "frames.mjpeg").read_bytes()
        for row in (listed[0], listed[len(listed) // 2], listed[-1]):
            r = httpx.get(f"{base}/api/sessions/{sid}/files/{row['file']}")
            assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg"
            assert "max-age" in r.headers["cache-control"]  # a listed frame never changes
            start = int(row["offset"])
            assert r.content == pack[start : start + int(row["bytes"])]
            assert r.content.startswith(b"\xff\xd8") and r.content.endswith(b"\xff\xd9")
    last = int(rows["front"][-1]["seq"])
    for missing in (f"front/{last + 1000:08d}.jpg", "left/00000001.jpg", "front/1.jpg"):
        r = httpx.get(f"{base}/api/sessions/{sid}/files/{missing}")
        assert r.status_code == 404, missing
    r = httpx.get(f"{base}/api/sessions/{sid}/files/front/..%2F..%2F..%2Fetc%2Fpasswd")
    assert r.status_code == 400
    zf = zipfile.ZipFile(io.BytesIO(httpx.get(f"{base}/api/sessions/{sid}/download").content))
    info = zf.getinfo(f"{sid}/front/frames.mjpeg")
    assert info.compress_type == zipfile.ZIP_STORED
    assert zf.read(info) == (folder / "front" / "frames.mjpeg").read_bytes()
    assert zf.getinfo(f"{sid}/telemetry.csv").compress_type == zipfile.ZIP_DEFLATED


def test_a_format_1_session_is_still_listed_served_and_zipped(camera_server):
    """A session recorded before the frame pack (a JPEG file per frame) is read as
    before: its frames counted and served as files, its zip holds them."""
    import shutil

    from tests.recording_fakes import as_format_1

    base, root = camera_server
    sid = record_session(base, 1.0)
    old = "20200101T000000Z_sim"
    shutil.copytree(root / sid, root / old)
    as_format_1(root / old)
    rows = frame_rows(root / old, "front")
    assert "offset" not in rows[0] and not (root / old / "front" / "frames.mjpeg").exists()
    detail = httpx.get(f"{base}/api/sessions/{old}").json()
    assert detail["meta"]["format_version"] == 1
    assert detail["frame_files"] == httpx.get(f"{base}/api/sessions/{sid}").json()["frame_files"]
    assert not any(f.endswith(".jpg") for f in detail["files"])
    for row in (rows[0], rows[-1]):
        want = httpx.get(f"{base}/api/sessions/{sid}/files/{row['file']}").content
        r = httpx.get(f"{base}/api/sessions/{old}/files/{row['file']}")
        assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg"
        assert r.content == want == (root / old / row["file"]).read_bytes()
    zf = zipfile.ZipFile(io.BytesIO(httpx.get(f"{base}/api/sessions/{old}/download").content))
    info = zf.getinfo(f"{old}/{rows[0]['file']}")
    assert info.compress_type == zipfile.ZIP_STORED


def test_a_live_sessions_frames_are_served_as_frames_csv_grows(camera_server):
    """While a session records, frames.csv grows: the index the route keeps is extended,
    so a frame listed after the first request is served too, and the count follows."""
    from tests.helpers import wait_until

    base, root = camera_server
    sid = httpx.post(f"{base}/api/recording/start").json()["id"]
    folder = root / sid
    try:
        assert wait_until(lambda: len(frame_rows(folder, "front")) >= 3, timeout=30)
        first = frame_rows(folder, "front")
        r = httpx.get(f"{base}/api/sessions/{sid}/files/{first[-1]['file']}")
        assert r.status_code == 200
        n_first = httpx.get(f"{base}/api/sessions/{sid}").json()["frame_files"]["front"]
        assert n_first >= len(first)
        assert wait_until(lambda: len(frame_rows(folder, "front")) >= n_first + 5, timeout=30)
        later = frame_rows(folder, "front")[-1]
        r = httpx.get(f"{base}/api/sessions/{sid}/files/{later['file']}")
        assert r.status_code == 200
        pack = (folder / "front" / "frames.mjpeg").read_bytes()
        start = int(later["offset"])
        assert r.content == pack[start : start + int(later["bytes"])]
        n_later = httpx.get(f"{base}/api/sessions/{sid}").json()["frame_files"]["front"]
        assert n_later >= n_first + 5
    finally:
        httpx.post(f"{base}/api/recording/stop")
