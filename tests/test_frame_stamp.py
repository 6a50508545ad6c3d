"""The twin's frames carry their counter and render time in a corner code that survives
the capture's resize and JPEG, and the real twin station's frames carry it."""

from __future__ import annotations

import time

import cv2
import httpx
import numpy as np
import pytest

from fpv_station.companion.cameras.frame_stamp import (
    TIME_MODULUS_MS,
    read_stamp,
    stamp,
    unwrap_ms,
)
from fpv_station.server.app import create_app
from tests.helpers import run_uvicorn, wait_until
from tests.twin_flights import twin_station_settings


@pytest.mark.parametrize("size", [(640, 480), (320, 240), (1280, 720)])
@pytest.mark.parametrize("quality", [50, 80])
def test_the_code_survives_resize_and_jpeg(size, quality):
    rng = np.random.default_rng(size[0] + quality)
    image = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)  # worst case: noise
    t_wall = 1_795_000_000.123
    stamp(image, 54321, t_wall)
    image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    decoded = cv2.imdecode(jpeg, cv2.IMREAD_COLOR)
    counter, t_ms32 = read_stamp(decoded)
    assert counter == 54321
    assert unwrap_ms(t_ms32, t_wall * 1000 + 5000) == round(t_wall * 1000)


def test_a_frame_without_the_code_reads_as_none():
    rng = np.random.default_rng(1)
    assert read_stamp(rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)) is None
    assert read_stamp(np.zeros((240, 320, 3), np.uint8)) is None


def test_unwrap_across_the_modulus():
    near = 3 * TIME_MODULUS_MS + 10.0
    assert unwrap_ms(TIME_MODULUS_MS - 5, near) == 3 * TIME_MODULUS_MS - 5
    assert unwrap_ms(20, near) == 3 * TIME_MODULUS_MS + 20


def test_the_twin_stations_frames_carry_counter_and_render_time(tmp_path):
    app = create_app(twin_station_settings(tmp_path, {"recording.auto_record_on_arm": False}))
    with run_uvicorn(app) as base:

        def snapshot():
            r = httpx.get(f"{base}/video/front.jpg", timeout=30)
            if r.status_code != 200:
                return None
            image = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
            return read_stamp(image), float(r.headers["X-Frame-Time"])

        assert wait_until(lambda: snapshot() is not None, timeout=60)
        (first, _), _ = snapshot(), None
        assert wait_until(lambda: snapshot()[0][0] > first[0], timeout=60)
        (counter, t_ms32), captured = snapshot()
        rendered_ms = unwrap_ms(t_ms32, time.time() * 1000)
        # Rendered just before its capture time was taken (the code rounds to the ms),
        # and not in the future.
        assert -1 <= captured * 1000 - rendered_ms < 60_000
        assert rendered_ms <= time.time() * 1000
