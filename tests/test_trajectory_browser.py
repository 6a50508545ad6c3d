"""Headless Chromium on the real station: the pilot page's 3D panel (the viser client served
by the station's viser server, offline) shows the flown path, and the replay page draws a
recorded path with its time slider and frames. Pixels are checked, not just page loads."""

from __future__ import annotations

import contextlib
import time

import cv2
import httpx
import numpy as np
import pytest

from fpv_station.server.app import create_app
from tests.helpers import panel_station_settings, run_uvicorn, wait_until
from tests.pages import open_offline
from tests.synthetic import SESSION_A, SESSION_B, state_at

TOKEN = "browser-test-token"


class HeldFirst:
    """The page's first request to `pattern` held at the network until `release()`; each
    later one goes through and is noted in `later` (a request the page should not have
    sent while the first was in flight). Playwright runs the handler inside its own calls,
    so the test waits in the page (`page.wait_for_timeout`)."""

    def __init__(self, page, pattern: str) -> None:
        self.held: list = []
        self.later: list = []
        page.route(pattern, self._route)

    def _route(self, route) -> None:
        if not self.held:
            self.held.append(route)
            return
        self.later.append(route)
        route.continue_()

    def release(self) -> None:
        """Let the held request go (later ones already go as they come)."""
        self.held[0].continue_()


def saturated(png: bytes) -> np.ndarray:
    """Mask of strongly coloured pixels (paths and markers; not grids, text or white)."""
    decoded = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert decoded is not None, "not a PNG"
    img = decoded.astype(int)
    return (img.max(axis=2) - img.min(axis=2)) > 70


@pytest.fixture
def station(two_sessions_dir):
    app = create_app(panel_station_settings(two_sessions_dir, TOKEN))
    with run_uvicorn(app) as base:
        yield base, app


@pytest.mark.timeout(300)  # the viser client renders in software here
def test_pilot_page_3d_panel_draws_the_flown_path(station, browser, tmp_path):
    base, app = station
    # Feed a flight through the station's state slot, as the link does.
    slot = app.state.station.state
    for i in range(400):
        slot.publish(state_at(i * 0.1))
        time.sleep(0.004)
    # The panel keeps the trail; nobody watches yet, so nothing is drawn (sent) so far.
    assert wait_until(lambda: httpx.get(f"{base}/api/viser").json()["points"] > 50, 5.0)
    assert httpx.get(f"{base}/api/viser").json()["chunks"] == 0
    outside: list[str] = []
    page = open_offline(browser, outside)
    with contextlib.closing(page.context):  # the module's browser runs on
        page.goto(f"{base}/?token={TOKEN}")  # as the station prints it: the pilot's page
        panel = page.locator("#panel-3d")
        assert panel.is_hidden()
        page.locator("#p3d-toggle").click()
        assert panel.is_visible()
        page.locator("#p3d-enlarge").click()  # the panel can be enlarged
        assert "p3d-large" in (panel.get_attribute("class") or "")
        # viser's client through the station's own port, told to connect with the token.
        viser_url = f"{base}/3d/live/"
        ws = base.replace("http://", "ws://")
        assert page.locator("#p3d-frame").get_attribute("src") == (
            f"/3d/live/?websocket={ws}/3d/live?token={TOKEN}"
        )
        # The viser client may add query parameters to its own URL once it runs. Poll with
        # Playwright's own wait: a plain sleep would not let it process frame events.
        for _ in range(600):
            if any(f.url.startswith(viser_url) for f in page.frames):
                break
            page.wait_for_timeout(100)
        frame = next((f for f in page.frames if f.url.startswith(viser_url)), None)
        assert frame is not None, [f.url for f in page.frames]
        frame.locator("canvas").first.wait_for(timeout=90_000)
        clear = frame.get_by_role("button", name="Clear trail")
        try:
            clear.wait_for(timeout=90_000)
        except Exception:
            page.screenshot(path=str(tmp_path / "panel3d_failed.png"))
            raise
        # The first viewer gets the whole trail drawn, with no telemetry flowing.
        assert wait_until(lambda: httpx.get(f"{base}/api/viser").json()["chunks"] >= 2, 10.0)
        page.wait_for_timeout(2500)  # let the software renderer draw the scene
        with_path = panel.screenshot(path=str(tmp_path / "panel3d.png"), timeout=90_000)
        clear.click()  # the viser GUI's own button: the trail goes, the rest stays
        assert wait_until(lambda: httpx.get(f"{base}/api/viser").json()["chunks"] == 0, 5.0)
        page.wait_for_timeout(1500)
        without_path = panel.screenshot(path=str(tmp_path / "panel3d_cleared.png"), timeout=90_000)
        path_px = saturated(with_path) & ~saturated(without_path)
        assert path_px.sum() > 300, f"only {path_px.sum()} path pixels in the 3D panel"

        # Follow: the viewer's camera is moved onto the vehicle as it flies.
        frame.get_by_text("Follow vehicle").click()
        service = app.state.station.trajectory3d
        assert wait_until(lambda: service.controls.follow, 5.0)
        for i in range(400, 420):
            slot.publish(state_at(i * 0.1))
            time.sleep(0.03)
        vehicle = np.asarray(service.scene.vehicle.position)

        def cameras_on_vehicle() -> bool:  # as the browser reports its camera back
            cams = [np.asarray(c.camera.look_at) for c in service.server.get_clients().values()]
            return bool(cams) and all(np.allclose(c, vehicle, atol=0.5) for c in cams)

        assert wait_until(cameras_on_vehicle, 10.0)

    assert outside == [], f"requests left the station: {outside[:5]}"


# Click Play, and Pause once the slider's time is past 12 s: [play, pause] on the page's
# clock (ms).
PLAY_PAST_12_S = """() => new Promise((resolve) => {
  const button = document.getElementById('replay-play');
  button.click();
  const played = performance.now();
  const poll = () => {
    if (parseFloat(document.getElementById('replay-time').textContent) <= 12.0) {
      setTimeout(poll, 10);
      return;
    }
    button.click();
    resolve([played, performance.now()]);
  };
  poll();
})"""


@pytest.mark.timeout(300)  # the 3D replay panel renders in software here
def test_replay_page_draws_sessions_with_slider_frames_and_play(station, browser, tmp_path):
    base, app = station
    outside: list[str] = []
    page = open_offline(browser, outside)
    with contextlib.closing(page.context):  # the module's browser runs on
        # Replay: picked from the sessions page, a second session overlaid in the paper's frame.
        # One load of the 3D panel in flight at a time: the first (the session alone) is
        # held at the network while the overlay is picked; a second load sent meanwhile
        # could reach the station first and be undone by the held one.
        loads = HeldFirst(page, "**/api/replay3d")
        page.goto(f"{base}/sessions.html?token={TOKEN}")  # kept by lib.js
        page.locator(f'tr[data-id="{SESSION_A}"] a.replay').click()
        page.wait_for_url(f"**/replay.html?session={SESSION_A}*")
        page.wait_for_function(
            "document.getElementById('replay-status').textContent.includes('fixes')", timeout=30_000
        )
        # The route's handler runs inside Playwright's calls: wait in the page, not here.
        in_page = lambda s: page.wait_for_timeout(s * 1000)  # noqa: E731
        assert wait_until(lambda: bool(loads.held), 30.0, 0.1, in_page), "no 3D panel load"
        page.locator("#replay-compare").select_option(SESSION_B)  # also turns alignment on
        page.wait_for_function(
            "document.getElementById('replay-status').textContent.includes('overlay')",
            timeout=30_000,
        )
        page.wait_for_timeout(1000)  # room for a second load, were one allowed in flight
        assert loads.later == [], "a second 3D panel load went out while the first was in flight"
        loads.release()
        assert wait_until(lambda: bool(loads.later), 30.0, 0.1, in_page), "the overlay never loaded"
        slider = page.locator("#replay-slider")
        assert slider.is_visible() and int(slider.get_attribute("max")) > 300
        slider.evaluate("el => { el.value = 300; el.dispatchEvent(new Event('input')); }")
        assert page.locator("#replay-time").text_content().startswith("30.0")
        page.wait_for_function(
            "['replay-front', 'replay-bottom']"
            ".every(id => document.getElementById(id).naturalWidth > 0)",
            timeout=30_000,
        )
        front_src = page.locator("#replay-front").get_attribute("src")
        # The newest frame captured at or before the instant, on the session clock as the
        # slider: 5 fps, so frame 150 at 30 s.
        reply = httpx.get(f"{base}/api/sessions/{SESSION_A}/trajectory").json()
        index = reply["frame_index"]["front"]
        k = max(k for k, t in enumerate(index["t_s"]) if t <= 30.0)
        assert front_src.endswith(index["file"][k]) and index["file"][k].endswith("150.jpg")
        png = page.locator("#replay-top").screenshot(path=str(tmp_path / "replay.png"))
        img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR).astype(int)
        b, g, r = img[..., 0], img[..., 1], img[..., 2]
        overlay = (r > 120) & (b > 150) & (g < 130)  # the compared session, purple
        assert saturated(png).sum() > 1500, "the replay canvas shows no path"
        assert overlay.sum() > 200, "the second session is not overlaid"
        # Play at 8x from 5 s until past 12 s, then pause: both clicks from inside the page,
        # timed on its clock (a loaded machine may take long to get there, not change the
        # speed): 8 s of flight per second of the page's clock between them.
        slider.evaluate("el => { el.value = 50; el.dispatchEvent(new Event('input')); }")
        page.locator("#replay-speed").select_option("8")
        played_ms, paused_ms = page.evaluate(PLAY_PAST_12_S)
        t_played = float(page.locator("#replay-time").text_content().split("/")[0])
        assert t_played > 12.0
        assert t_played == pytest.approx(5.0 + 8 * (paused_ms - played_ms) / 1000, abs=0.15)

        # The 3D replay panel: the station's replay viser server, showing both sessions and
        # following the slider (PUT /api/replay3d/time, throttled).
        replay3d = app.state.station.replay3d
        viser_url = f"{base}/3d/replay/"  # through the station's own port
        assert page.locator("#replay-3d").get_attribute("src") == "/3d/replay/"
        assert wait_until(
            lambda: (
                replay3d.primary is not None
                and replay3d.overlay is not None
                and (replay3d.primary.id, replay3d.overlay.id) == (SESSION_A, SESSION_B)
                and abs(replay3d.t_s - t_played) < 0.2
            ),
            60.0,  # a hang guard: the page's last PUT of the time may come late under load
        )
        # One instant in flight at a time. The PUT of 10 s is held at the network while the
        # slider moves on to 20 s: a second PUT sent meanwhile would reach the station
        # first and leave the panel at 10 s once the held one arrives.
        times = HeldFirst(page, "**/api/replay3d/time")
        slider.evaluate("el => { el.value = 100; el.dispatchEvent(new Event('input')); }")
        assert wait_until(lambda: bool(times.held), 30.0, 0.1, in_page), "no PUT of the time"
        slider.evaluate("el => { el.value = 200; el.dispatchEvent(new Event('input')); }")
        page.wait_for_timeout(1000)  # room for a second PUT, were one allowed in flight
        assert times.later == [], "a second PUT went out while the first was in flight"
        times.release()
        at_20 = lambda: abs(replay3d.t_s - 20.0) < 1e-6  # noqa: E731
        assert wait_until(at_20, 60.0, 0.1, in_page), replay3d.t_s
        frame = next((f for f in page.frames if f.url.startswith(viser_url)), None)
        assert frame is not None, [f.url for f in page.frames]
        frame.locator("canvas").first.wait_for(timeout=90_000)
        # a narrow panel gets viser's bottom sheet: fold it away, as a user would
        frame.get_by_text("fpv-station replay 3D").first.click(timeout=90_000)
        page.wait_for_timeout(2500)  # let the software renderer draw the scene
        png3d = page.locator("#replay-3d").screenshot(
            path=str(tmp_path / "replay3d.png"), timeout=90_000
        )
        img = cv2.imdecode(np.frombuffer(png3d, np.uint8), cv2.IMREAD_COLOR).astype(int)
        b, g, r = img[..., 0], img[..., 1], img[..., 2]
        assert saturated(png3d).sum() > 500, "the 3D replay panel shows no path"
        purple = (r > 110) & (b > 150) & (g < 100)  # only the overlay is this colour
        assert purple.sum() > 50, "the second session is not drawn in the 3D replay panel"
    assert outside == [], f"requests left the station: {outside[:5]}"
