"""The pilot page shows both cameras with their fps and latency (real chromium)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import threading
import time
from collections.abc import Awaitable, Callable

import cv2
import numpy as np
import pytest
from playwright.sync_api import expect
from starlette.routing import WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from fpv_station.companion.video_frame import Frame
from fpv_station.server.app import create_app
from fpv_station.server.video_fanout import ws_message
from tests.helpers import run_uvicorn, station_settings, wait_until
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


class ScriptedVideo:
    """The station's /ws/video replaced at the protocol boundary by a scripted one, on a
    real socket: the page's video socket lives in a worker, which Playwright's
    `route_web_socket` does not reach. `script(ws, n)` serves the n-th connection (from
    1) on the event loop."""

    def __init__(self) -> None:
        self.script: Callable[[WebSocket, int], Awaitable[None]] | None = None
        self.connections = 0

    async def serve(self, ws: WebSocket) -> None:
        await ws.accept()
        self.connections += 1
        assert self.script is not None
        with contextlib.suppress(WebSocketDisconnect):
            await self.script(ws, self.connections)


async def until_subscribed(ws: WebSocket) -> None:
    while "subscribe" not in await ws.receive_text():
        pass


@pytest.fixture(scope="module")
def bare_station():
    """A station without cameras whose /ws/video each test scripts (`ScriptedVideo`)."""
    app = create_app(station_settings("none"))
    video = ScriptedVideo()
    app.router.routes.insert(0, WebSocketRoute("/ws/video", video.serve))
    with run_uvicorn(app) as base:
        yield base, video


# Instruments the browser's decoder in the page's video worker, not our code: counts the
# decodes started and holds them until the test lets them go.
HELD_DECODES = """() => {
  self.__decodes = 0;
  let release; const gate = new Promise((r) => { release = r; });
  self.__release = () => release();
  const decode = self.createImageBitmap.bind(self);
  self.createImageBitmap = (...args) => { self.__decodes += 1; return gate.then(() => decode(...args)); };
}"""


def pilot_page_and_worker(browser, base: str):
    """A pilot page and its video worker, to instrument before the station sends frames."""
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    with page.expect_worker() as started:
        page.goto(base + "/")
    return page, started.value


def test_frames_that_arrive_during_a_decode_are_skipped_but_the_newest(bare_station, browser):
    """A burst of frames while one is being decoded: the page decodes that one and then
    only the newest, and draws the newest (the frames between cost no decode)."""
    base, video = bare_station
    jpeg = cv2.imencode(".jpg", np.full((240, 320, 3), 90, np.uint8))[1].tobytes()
    burst = 8
    front = [
        ws_message("front", Frame("front", seq, jpeg, 320, 240, 0.0, time.time()))
        for seq in range(1, burst + 1)
    ]
    # Then one bottom frame: its decode starts once every front frame before it is in.
    bottom = ws_message("bottom", Frame("bottom", 1, jpeg, 320, 240, 0.0, time.time()))
    instrumented = threading.Event()

    async def station_socket(ws: WebSocket, n: int) -> None:
        await until_subscribed(ws)
        assert await asyncio.to_thread(instrumented.wait, 60)
        for message in (*front, bottom):
            await ws.send_bytes(message)
        while True:
            await ws.receive_text()  # acks

    video.script = station_socket
    page, worker = pilot_page_and_worker(browser, base)
    worker.evaluate(HELD_DECODES)
    instrumented.set()
    wait_until(lambda: worker.evaluate("self.__decodes") >= 2, timeout=30)
    assert worker.evaluate("self.__decodes") == 2  # the first front, the bottom
    worker.evaluate("self.__release()")
    page.wait_for_function(
        f"() => (window.fpvDebug.cameras.frames.front || {{}}).seq === {burst}",
        timeout=30_000,
    )
    assert worker.evaluate("self.__decodes") == 3  # and the newest front
    page.close()


# Instruments the browser in the page, not our code: its animation frames are held while
# `__holdFrames` is set (a page the browser gives no animation frames).
HELD_FRAMES = """() => {
  const raf = window.requestAnimationFrame.bind(window);
  const held = [];
  window.__holdFrames = true;
  window.requestAnimationFrame = (cb) => { if (!window.__holdFrames) return raf(cb); held.push(cb); return 0; };
  window.__releaseFrames = () => { window.__holdFrames = false; for (const cb of held.splice(0)) raf(cb); };
}"""


def test_a_page_given_no_animation_frames_asks_for_few_and_draws_them_as_they_come(
    bare_station, browser
):
    """Frames come at 30 fps to a page that is given no animation frames (a background
    tab that still reads as visible). Once a picture has waited for one, the page asks
    the station for 5 frames a second, draws each frame as it is decoded and acknowledges
    it: the pictures it holds are fresh. None has a latency to the screen: none was
    shown. Given animation frames again, it asks for every frame, and the picture on its
    canvas is shown and timed."""
    base, video = bare_station
    jpeg = cv2.imencode(".jpg", np.full((240, 320, 3), 90, np.uint8))[1].tobytes()
    sent = 46
    instrumented = threading.Event()
    said: list[dict] = []

    async def station_socket(ws: WebSocket, n: int) -> None:
        await until_subscribed(ws)  # the first subscription, every frame: not in `said`
        assert await asyncio.to_thread(instrumented.wait, 60)
        listener = asyncio.ensure_future(listen(ws))
        for seq in range(1, sent + 1):
            frame = Frame("front", seq, jpeg, 320, 240, 0.0, time.time())
            await ws.send_bytes(ws_message("front", frame))
            await asyncio.sleep(1 / 30)
        await listener

    async def listen(ws: WebSocket) -> None:
        while True:
            said.append(json.loads(await ws.receive_text()))

    def pace() -> list:
        return [m["max_fps"] for m in said if "subscribe" in m]

    video.script = station_socket
    page, _ = pilot_page_and_worker(browser, base)
    page.evaluate(HELD_FRAMES)
    instrumented.set()
    assert wait_until(lambda: pace() == [5], timeout=60), said
    page.wait_for_function(  # polled on a timer: the animation frames are held
        f"() => (window.fpvDebug.cameras.frames.front || {{}}).seq === {sent}",
        polling=100,
        timeout=30_000,
    )
    assert page.evaluate("window.fpvDebug.cameras.starved") is True
    # Every frame drawn, replaced or skipped is acknowledged (the page acks even counts).
    assert wait_until(lambda: [m["ack"] for m in said if "ack" in m][-1:] == [sent], timeout=30)
    assert page.evaluate("window.fpvDebug.cameras.latency.front || null") is None
    page.evaluate("window.__releaseFrames()")
    assert wait_until(lambda: pace() == [5, None], timeout=30), said
    assert page.evaluate("window.fpvDebug.cameras.starved") is False
    # The animation frames' first shows the picture drawn last: a latency of its own.
    page.wait_for_function("() => window.fpvDebug.cameras.latency.front", timeout=30_000)
    page.close()


def test_a_restarted_station_s_frames_are_drawn_though_they_count_from_1_again(
    bare_station, browser
):
    """The video socket closes and the page reconnects to a station whose frames count
    from 1 again: they are drawn, not taken for old frames."""
    base, video = bare_station
    jpeg = cv2.imencode(".jpg", np.full((240, 320, 3), 90, np.uint8))[1].tobytes()
    restart = threading.Event()
    first = video.connections + 1

    async def station_socket(ws: WebSocket, n: int) -> None:
        seq = 50 if n == first else 1  # the first station, then the restarted one
        await until_subscribed(ws)
        await ws.send_bytes(
            ws_message("front", Frame("front", seq, jpeg, 320, 240, 0.0, time.time()))
        )
        if n == first:
            await asyncio.to_thread(restart.wait, 60)
            await ws.close()
            return
        while True:
            await ws.receive_text()

    video.script = station_socket
    drawn = "() => (window.fpvDebug.cameras.frames.front || {}).seq"
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    page.goto(base + "/")
    page.wait_for_function(f"{drawn} === 50", timeout=30_000)
    restart.set()
    page.wait_for_function(f"{drawn} === 1", timeout=30_000)
    page.close()
