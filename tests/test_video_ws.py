"""`WS /ws/video` through a real uvicorn: a page gets the cameras it subscribes to, and
only those, as shared JPEG messages; unacknowledged frames are bounded and the newest
wins; a page that asks for a pace is sent each camera at most that often; other sites are refused and the connection counts among the video clients."""

from __future__ import annotations

import json
import math
import struct
import time

import cv2
import httpx
import numpy as np
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from fpv_station.server.app import create_app
from fpv_station.server.routes.video_ws import MIN_PACED_FPS, interval_of
from tests.helpers import run_uvicorn, station_settings, wait_until
from tests.video_fixtures import write_images


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    root = tmp_path_factory.mktemp("video")
    specs = {}
    for name in ("front", "bottom"):
        folder = write_images(root / name, 6, (320, 240))
        specs |= {
            f"cameras.{name}.spec": f"folder:{folder}",
            f"cameras.{name}.width": 320,
            f"cameras.{name}.height": 240,
        }
    settings = station_settings("none", **specs, **{"server.max_video_clients": 2})
    with run_uvicorn(create_app(settings)) as url:
        yield url


def parse(message: bytes) -> tuple[dict, bytes]:
    (n,) = struct.unpack(">H", message[:2])
    return json.loads(message[2 : 2 + n]), message[2 + n :]


def clients(base: str) -> dict[str, int]:
    return {c["name"]: c["clients"] for c in httpx.get(f"{base}/api/cameras").json()["cameras"]}


def test_only_the_subscribed_cameras_are_sent(base):
    ws_url = base.replace("http", "ws") + "/ws/video"
    with connect(ws_url, origin=base, open_timeout=10) as ws:
        ws.send(json.dumps({"subscribe": ["front"]}))
        heads = []
        for _ in range(5):
            head, jpeg = parse(ws.recv(timeout=30))
            heads.append(head)
        assert {h["camera"] for h in heads} == {"front"}
        assert all(b["seq"] > a["seq"] for a, b in zip(heads, heads[1:], strict=False))
        assert heads[-1]["signal"] is True and heads[-1]["t"] > 1e9
        image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        assert image.shape == (240, 320, 3)
        assert wait_until(lambda: clients(base) == {"front": 1, "bottom": 0}, timeout=15)
        # A hidden view: the page takes the bottom camera instead; the front one stops.
        ws.send(json.dumps({"subscribe": ["bottom", "no-such-camera"]}))
        assert wait_until(lambda: clients(base) == {"front": 0, "bottom": 1}, timeout=15)
        while parse(ws.recv(timeout=30))[0]["camera"] != "bottom":
            pass  # frames sent before the change
        assert {parse(ws.recv(timeout=30))[0]["camera"] for _ in range(5)} == {"bottom"}
    assert wait_until(lambda: clients(base) == {"front": 0, "bottom": 0}, timeout=15)


def test_unacknowledged_frames_are_bounded_and_the_newest_is_sent_next(base):
    ws_url = base.replace("http", "ws") + "/ws/video?ack=2"
    with connect(ws_url, origin=base, open_timeout=10) as ws:
        ws.send(json.dumps({"subscribe": ["front"]}))
        first = [parse(ws.recv(timeout=30))[0]["seq"] for _ in range(2)]
        with pytest.raises(TimeoutError):  # the window is full: nothing more comes
            ws.recv(timeout=1.5)
        ws.send(json.dumps({"ack": 2}))
        nxt = parse(ws.recv(timeout=30))[0]["seq"]
        # The frames made while the page was busy were skipped, not queued.
        assert nxt > first[-1] + 1, (first, nxt)


def per_camera(ws, seconds: float) -> tuple[dict[str, int], float]:
    """The frames of each camera received for `seconds`, and the time they took."""
    counts = {"front": 0, "bottom": 0}
    start = time.monotonic()
    while (left := start + seconds - time.monotonic()) > 0:
        try:
            counts[parse(ws.recv(timeout=left))[0]["camera"]] += 1
        except TimeoutError:
            break
    return counts, time.monotonic() - start


def test_a_paced_page_is_sent_each_camera_at_most_max_fps(base):
    """`{"max_fps": 2}`: each camera's frames are half a second apart at least, on the
    station's clock; `null` lifts it. Every frame counted was sent after the request
    (nothing was subscribed before), so in t seconds at most 2t + 1 of them."""
    ws_url = base.replace("http", "ws") + "/ws/video"
    with connect(ws_url, origin=base, open_timeout=10) as ws:
        start = time.monotonic()
        ws.send(json.dumps({"subscribe": ["front", "bottom"], "max_fps": 2}))
        counts, _ = per_camera(ws, 3.0)
        bound = math.floor((time.monotonic() - start) * 2) + 1
        assert all(1 <= n <= bound for n in counts.values()), (counts, bound)
        ws.send(json.dumps({"max_fps": None}))  # (a paced frame may still come first)
        counts, took = per_camera(ws, 3.0)
        assert all(n > math.floor(took * 2) + 1 for n in counts.values()), (counts, took)


@pytest.mark.parametrize(
    ("max_fps", "interval"),
    [
        (5, 0.2),
        (2.5, 0.4),
        (0.01, 1 / MIN_PACED_FPS),
        (None, 0.0),
        (0, 0.0),
        (-3, 0.0),
        (math.inf, 0.0),
        (10**400, 0.0),
        (math.nan, 0.0),
        (True, 0.0),
        ("5", 0.0),
        ([5], 0.0),
    ],
)
def test_max_fps_is_a_positive_number_or_no_pace(max_fps, interval):
    assert interval_of(max_fps) == pytest.approx(interval)


def test_other_sites_are_refused_and_each_page_takes_a_video_place(base):
    ws_url = base.replace("http", "ws") + "/ws/video"
    with pytest.raises(InvalidStatus) as exc:
        connect(ws_url, origin="http://evil.example", open_timeout=10)
    assert exc.value.response.status_code == 403
    with (
        connect(ws_url, origin=base, open_timeout=10),
        connect(ws_url, origin=base, open_timeout=10),
    ):
        with pytest.raises(InvalidStatus) as exc:  # server.max_video_clients is 2
            connect(ws_url, origin=base, open_timeout=10)
        assert exc.value.response.status_code == 503
    # Places are given back when pages leave.
    with connect(ws_url, origin=base, open_timeout=10) as ws:
        ws.send(json.dumps({"subscribe": ["front"]}))
        assert parse(ws.recv(timeout=30))[0]["camera"] == "front"
