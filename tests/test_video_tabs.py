"""Every tab live: six pages in one browser (three pilot pages, two goggles, sessions) in
real headless Chromium against the real twin. Each page's frames advance, its OSD's VID
reads the age of the frame drawn, and its `/api` requests answer: the pages take their video over one
WebSocket each, not one HTTP connection per MJPEG stream (Chromium has six per host).
A camera no page shows is not streamed: the goggles' hidden picture-in-picture. The OSD
shows the twin's render-to-screen latency, read from the code in each frame's corner."""

from __future__ import annotations

import re

import httpx
import pytest
from playwright.sync_api import expect

from fpv_station.server.app import create_app
from tests.helpers import chromium, run_uvicorn, wait_until
from tests.pages import SIX_TABS as PAGES
from tests.twin_flights import twin_station_settings

# Hang guards, generous: six pages and the twin on a loaded two-core machine.
GUARD_MS = 120_000


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    overrides = {"recording.auto_record_on_arm": False}
    for name in ("front", "bottom"):  # small frames: six pages decode them on two cores
        overrides |= {
            f"cameras.{name}.width": 320,
            f"cameras.{name}.height": 240,
            f"cameras.{name}.fps": 10,
        }
    app = create_app(twin_station_settings(tmp_path_factory.mktemp("sessions"), overrides))
    with run_uvicorn(app) as url:
        # A flight task: the goggles' OSD shows its step as a line beside the latency's.
        tasks = httpx.get(f"{url}/api/task", timeout=30).json()["tasks"]
        httpx.post(f"{url}/api/task", json={"task_id": tasks[0]["id"]}, timeout=30)
        yield url


def clients(base: str) -> dict[str, int]:
    cams = httpx.get(f"{base}/api/cameras", timeout=30).json()["cameras"]
    return {c["name"]: c["clients"] for c in cams}


def frames_advance(page, camera: str) -> None:
    """The camera's view draws frames: its canvas's count of frames drawn (data-frames) grows."""
    drawn = f"+(document.querySelector('canvas[data-camera={camera}]').dataset.frames || 0)"
    page.wait_for_function(f"() => {drawn} > 0", timeout=GUARD_MS)
    count = page.evaluate(f"() => {drawn}")
    page.wait_for_function(f"() => {drawn} > {count}", timeout=GUARD_MS)


def api_answers(page) -> None:
    status = page.evaluate(
        """() => Promise.race([
          fetch('/api/status').then((r) => r.status),
          new Promise((done) => setTimeout(() => done('no answer'), 30000))])"""
    )
    assert status == 200, status


@pytest.mark.timeout(600)  # six pages and the twin on two shared cores: a hang guard
def test_six_tabs_in_one_browser_stay_live(station):
    with chromium() as browser:
        context = browser.new_context(viewport={"width": 1280, "height": 720})
        pages = []
        for path in PAGES:
            page = context.new_page()
            page.goto(station + path, timeout=GUARD_MS)  # a page that cannot load hangs here
            pages.append(page)
        for page, path in zip(pages, PAGES, strict=True):
            if path != "/sessions.html":
                frames_advance(page, "front")
                # VID: the age of the newest frame drawn (how far under a second it
                # stays is the machine's load, not asserted here).
                expect(page.locator(".osd-age").first).to_contain_text(
                    re.compile(r"VID \d+\.\ds"), timeout=GUARD_MS
                )
            if path == "/":
                frames_advance(page, "bottom")
            api_answers(page)
        # Pilot pages show both cameras; goggles the front one, their PiP is hidden.
        assert wait_until(lambda: clients(station) == {"front": 5, "bottom": 3}, timeout=30)
        goggles = pages[3]
        assert page_has_no_frames(goggles, "bottom")
        goggles.keyboard.press("b")  # the PiP shown: its camera streams
        frames_advance(goggles, "bottom")
        assert wait_until(lambda: clients(station)["bottom"] == 4, timeout=30)
        goggles.keyboard.press("b")
        assert wait_until(lambda: clients(station)["bottom"] == 3, timeout=30)
        for page in pages:  # still live after all that
            api_answers(page)
        # The twin's frames carry their render time: the pages read it as they draw them.
        for page in (pages[0], pages[3]):
            expect(page.locator(".osd-lines").first).to_contain_text(
                re.compile(r"R2S \d+/\d+ms"), timeout=GUARD_MS
            )
        # Side-by-side stereo: both eyes show the same lines in the same order.
        goggles.keyboard.press("s")
        for eye in ("#front-view", "#front-view-right"):
            expect(goggles.locator(f"{eye} .osd-lines")).to_have_text(
                re.compile(r"^R2S \d+/\d+ms\s*next: arm$"), timeout=GUARD_MS
            )
        lat = pages[0].evaluate("() => window.fpvDebug.cameras.latency.front")
        assert lat["kind"] == "render" and 0 < lat["stationP50"] <= lat["p50"] <= lat["p99"], lat
        context.close()


def page_has_no_frames(page, camera: str) -> bool:
    return page.evaluate(
        f"() => !document.querySelector('canvas[data-camera={camera}]').dataset.frames"
    )
