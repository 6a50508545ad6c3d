"""The pilot page shows both cameras with their fps and latency (real chromium)."""

from __future__ import annotations

import re
import time

import cv2
import numpy as np
import pytest
from playwright.sync_api import expect

from fpv_station.companion.video_frame import Frame
from fpv_station.server.app import create_app
from fpv_station.server.video_fanout import ws_message
from tests.helpers import run_uvicorn, station_settings
from tests.video_fixtures import write_images


def test_page_shows_both_streams_with_fps_and_latency(tmp_path, browser):
    front = write_images(tmp_path / "front", 4, (320, 240))
    settings = station_settings(
        "none",
        **{
            "cameras.front.spec": f"folder:{front}?width=320&height=240",
            "cameras.bottom.spec": "v4l2:/dev/video-unplugged",  # shows NO SIGNAL
            "cameras.bottom.width": 320,
            "cameras.bottom.height": 240,
        },
    )
    with run_uvicorn(create_app(settings)) as base:
        page = browser.new_page(viewport={"width": 1280, "height": 720})
        page.goto(base + "/")
        for name in ("front", "bottom"):
            page.wait_for_function(
                f"""() => {{ const c = document.querySelector('#{name}-view .video-stream');
                  return c.dataset.frames > 0 && c.width === 320 && c.height === 240; }}""",
                timeout=30_000,
            )
        readout = re.compile(r"^\d+\.\d fps · \d+ ms · p99 \d+$")
        expect(page.locator("#front-readout")).to_have_text(readout, timeout=15_000)
        expect(page.locator("#bottom-readout")).to_have_text("NO SIGNAL", timeout=15_000)
        expect(page.locator("#bottom-readout")).to_have_attribute(
            "title", re.compile("does not exist")
        )
        # Paper's layout: the front view is large on the left, the bottom view on the right.
        front_box = page.locator("#front-view").bounding_box()
        bottom_box = page.locator("#bottom-view").bounding_box()
        assert front_box["x"] < bottom_box["x"] and front_box["width"] > 1.5 * bottom_box["width"]
        # The readout's figures: the delivered fps and the p50 latency to the screen.
        shown = page.locator("#front-readout").text_content()
        fps, latency_ms = re.match(r"^(\d+\.\d) fps · (\d+) ms", shown).groups()
        assert float(fps) > 10 and 0 <= int(latency_ms) < 1000, shown
        # The page holds exactly one stream per camera on the station, and no MJPEG one.
        cams = page.evaluate("async () => (await (await fetch('/api/cameras')).json()).cameras")
        assert {c["name"]: c["clients"] for c in cams} == {"front": 1, "bottom": 1}
        mjpeg = page.evaluate(
            "() => performance.getEntriesByType('resource').filter(e => e.name.includes('.mjpg'))"
            ".length"
        )
        assert mjpeg == 0


@pytest.fixture(scope="module")
def bare_station():
    """A station whose /ws/video each test replaces (`page.route_web_socket`)."""
    with run_uvicorn(create_app(station_settings("none"))) as base:
        yield base


# Instruments the browser's decoder, not our code: counts the decodes started and holds
# them until the test lets them go.
HELD_DECODES = """
  window.__decodes = 0;
  let release; const gate = new Promise((r) => { release = r; });
  window.__release = () => release();
  const decode = window.createImageBitmap.bind(window);
  window.createImageBitmap = (...args) => { window.__decodes += 1; return gate.then(() => decode(...args)); };
"""


def test_frames_that_arrive_during_a_decode_are_skipped_but_the_newest(bare_station, browser):
    """A burst of frames while one is being decoded: the page decodes that one and then
    only the newest, and draws the newest (the frames between cost no decode)."""
    jpeg = cv2.imencode(".jpg", np.full((240, 320, 3), 90, np.uint8))[1].tobytes()
    burst = 8
    front = [
        ws_message("front", Frame("front", seq, jpeg, 320, 240, 0.0, time.time()))
        for seq in range(1, burst + 1)
    ]
    # Then one bottom frame: its decode starts once every front frame before it is in.
    bottom = ws_message("bottom", Frame("bottom", 1, jpeg, 320, 240, 0.0, time.time()))

    def station_socket(ws) -> None:  # /ws/video's side, at the protocol boundary
        def on_message(text: str | bytes) -> None:
            if isinstance(text, str) and "subscribe" in text:
                for message in (*front, bottom):
                    ws.send(message)

        ws.on_message(on_message)

    page = browser.new_page(viewport={"width": 1280, "height": 720})
    page.add_init_script(HELD_DECODES)
    page.route_web_socket(re.compile(r".*/ws/video.*"), station_socket)
    page.goto(bare_station + "/")
    page.wait_for_function("() => window.__decodes >= 2", timeout=30_000)
    assert page.evaluate("() => window.__decodes") == 2  # the first front, the bottom
    page.evaluate("() => window.__release()")
    page.wait_for_function(
        f"() => (window.fpvDebug.cameras.frames.front || {{}}).seq === {burst}",
        timeout=30_000,
    )
    assert page.evaluate("() => window.__decodes") == 3  # and the newest front
    page.close()


def test_a_restarted_station_s_frames_are_drawn_though_they_count_from_1_again(
    bare_station, browser
):
    """The video socket closes and the page reconnects to a station whose frames count
    from 1 again: they are drawn, not taken for old frames."""
    jpeg = cv2.imencode(".jpg", np.full((240, 320, 3), 90, np.uint8))[1].tobytes()
    sockets = []

    def station_socket(ws) -> None:  # /ws/video's side, at the protocol boundary
        sockets.append(ws)
        seq = 50 if len(sockets) == 1 else 1  # the first station, then the restarted one

        def on_message(text: str | bytes) -> None:
            if isinstance(text, str) and "subscribe" in text:
                frame = Frame("front", seq, jpeg, 320, 240, 0.0, time.time())
                ws.send(ws_message("front", frame))

        ws.on_message(on_message)

    drawn = "() => (window.fpvDebug.cameras.frames.front || {}).seq"
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    page.route_web_socket(re.compile(r".*/ws/video.*"), station_socket)
    page.goto(bare_station + "/")
    page.wait_for_function(f"{drawn} === 50", timeout=30_000)
    sockets[0].close()
    page.wait_for_function(f"{drawn} === 1", timeout=30_000)
    page.close()
