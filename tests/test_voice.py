"""Voice callouts in headless Chromium against a real station following the test MAVLink
vehicle: what the page hands the browser's speech synthesis (stubbed at the browser's
boundary: there is no audio here) as the vehicle arms, changes mode, climbs, runs low on
battery, is recorded, goes silent and comes back, and as the task's step changes. On in
goggles, off on the pilot page until switched on; each callout can be switched off."""

from __future__ import annotations

import time

import httpx
import pytest
from playwright.sync_api import expect

from tests.stations import vehicle_station

# window.speechSynthesis replaced before the page's scripts run: what they speak is kept.
STUB = """(() => {
  window.__said = [];
  const stub = { speak(u) { window.__said.push(u.text); }, cancel() {}, pause() {}, resume() {},
    getVoices() { return []; }, pending: false, speaking: false, paused: false,
    addEventListener() {}, removeEventListener() {} };
  Object.defineProperty(window, "speechSynthesis", { value: stub, configurable: true });
})()"""


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    with vehicle_station(tmp_path_factory.mktemp("sessions")) as station:
        yield station


def on_the_ground(vehicle) -> None:
    """Disarmed on the ground in Position mode, with a full battery."""
    vehicle.disarm()
    vehicle.set_mode("POSCTL")
    vehicle.relative_alt_m, vehicle.remaining_pct = 0.0, 87


def said(page) -> list[str]:
    return page.evaluate("window.__said")


def wait_said(page, text: str) -> None:
    """Wait (a hang guard) until the page has said `text`; if it never does, say what it
    said and the station's state as the page last read it."""
    try:
        page.wait_for_function("(t) => window.__said.includes(t)", arg=text, timeout=60_000)
    except Exception as exc:
        seen = page.evaluate(
            "() => ({said: window.__said, recording: window.fpvDebug.voice.recording})"
        )
        raise AssertionError(f"never said {text!r}: {seen}") from exc


def open_page(browser, url: str):
    context = browser.new_context()
    context.add_init_script(STUB)
    page = context.new_page()
    page.goto(url)
    page.wait_for_function("window.fpvDebug && window.fpvDebug.feed.flowing()", timeout=60_000)
    return page


def wait_voice_ready(page) -> None:
    """Until the callouts know the vehicle and the recording as the page found them:
    what changes after that is news (a loaded box may run the first check late)."""
    page.wait_for_function(
        "() => window.fpvDebug.voice.heard && window.fpvDebug.voice.recording !== null",
        timeout=60_000,
    )


@pytest.mark.timeout(180)
def test_goggles_say_what_happens(station, browser):
    vehicle, base = station
    on_the_ground(vehicle)
    assert httpx.post(f"{base}/api/task", json={"task_id": 1}).status_code == 200
    page = open_page(browser, f"{base}/goggles.html")
    wait_voice_ready(page)
    wait_said(page, "Next: arm")  # the task's first step
    vehicle.arm()
    wait_said(page, "Armed")
    wait_said(page, "Next: take off")
    vehicle.set_mode("ALTCTL")
    wait_said(page, "Altitude mode")
    vehicle.relative_alt_m, vehicle.alt_m = 5.0, vehicle.alt_m + 5.0  # the default step: 5 m
    wait_said(page, "5 metres")
    vehicle.remaining_pct = 15
    wait_said(page, "Battery low, 15 percent")
    assert httpx.post(f"{base}/api/recording/start").status_code == 200
    wait_said(page, "Recording started")
    assert httpx.post(f"{base}/api/recording/stop").status_code == 200
    wait_said(page, "Recording stopped")
    vehicle.silent = True
    wait_said(page, "Link lost")
    vehicle.silent = False
    wait_said(page, "Link regained")
    vehicle.relative_alt_m, vehicle.alt_m = 0.0, vehicle.alt_m - 5.0
    vehicle.disarm()
    wait_said(page, "Disarmed")
    # Each said once: a callout is a change, not a state.
    for text in ("Armed", "Altitude mode", "5 metres", "Battery low, 15 percent", "Link lost"):
        assert said(page).count(text) == 1, (text, said(page))
    page.context.close()


@pytest.mark.timeout(120)
def test_goggles_that_load_their_modules_late_still_get_the_first_step(station, browser):
    """goggles.html runs task-panel.js as its own script before goggles.js's modules: with
    voice.js (and so goggles.js) held back at the network, the panel finds the first step
    before they can listen. They must still say it and show it on the OSD."""
    vehicle, base = station
    on_the_ground(vehicle)
    assert httpx.post(f"{base}/api/task", json={"task_id": 1}).status_code == 200
    context = browser.new_context()
    context.add_init_script(STUB)

    def after_the_panel(route) -> None:  # a slow link for one module, at the network
        time.sleep(3.0)  # the panel's /api/scene and /api/task (not held) answer meanwhile
        route.continue_()

    context.route("**/voice.js", after_the_panel)
    page = context.new_page()
    page.goto(f"{base}/goggles.html")
    wait_said(page, "Next: arm")
    expect(page.locator("[data-osd=task]")).to_have_text("next: arm", timeout=30_000)
    assert said(page).count("Next: arm") == 1, said(page)
    context.close()


@pytest.mark.timeout(120)
def test_pilot_page_is_quiet_until_switched_on_and_each_callout_switches_off(station, browser):
    vehicle, base = station
    on_the_ground(vehicle)
    httpx.post(f"{base}/api/task", json={"task_id": None})
    page = open_page(browser, f"{base}/")
    wait_voice_ready(page)
    vehicle.arm()
    page.wait_for_function(
        "document.querySelector('[data-osd=armed]').textContent === 'ARMED'", timeout=30_000
    )
    vehicle.disarm()
    page.wait_for_function(
        "document.querySelector('[data-osd=armed]').textContent === 'DISARMED'", timeout=30_000
    )
    assert said(page) == []  # off by default on the pilot page
    page.locator(".voice-menu summary").click()
    page.locator("[data-voice=on]").check()
    page.locator("[data-voice=mode]").uncheck()
    vehicle.set_mode("ALTCTL")  # not said: switched off
    vehicle.arm()
    wait_said(page, "Armed")
    assert "Altitude mode" not in said(page), said(page)
    # The choice is kept for the next visit.
    page.reload()
    page.locator(".voice-menu summary").click()
    assert page.locator("[data-voice=on]").is_checked()
    assert not page.locator("[data-voice=mode]").is_checked()
    vehicle.disarm()
    page.context.close()
