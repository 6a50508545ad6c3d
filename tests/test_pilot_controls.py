"""The pilot's controls for the twin in real headless chromium against a real station on
the twin: touch sticks on a phone (touches go in through the DevTools protocol, as a
touch screen's do), the gamepad panel's live axis bars, and a refusal shown with its
reason."""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

from fpv_station.server.app import create_app
from tests.helpers import (
    arm_and_climb,
    run_uvicorn,
    sticks_on,
    wait_until,
)
from tests.twin_flights import NO_ONBOARD_LOG, SMALL_CAMERAS, twin_station_settings


@pytest.fixture()
def twin_station(tmp_path):
    # The twin at twice real time, flown by the page's sticks: no recording on arming.
    settings = twin_station_settings(
        tmp_path,
        {
            "twin.realtime_factor": 2.0,
            "recording.auto_record_on_arm": False,
            **SMALL_CAMERAS,
            **NO_ONBOARD_LOG,
        },
    )
    app = create_app(settings)
    with run_uvicorn(app) as url:
        assert wait_until(lambda: state(app) and state(app).gps.fix_type == 3, timeout=15)
        yield app, url


def state(app):
    latest = app.state.station.state.get()
    return latest.value if latest else None


class Finger:
    """One finger on the touch screen, through CDP Input.dispatchTouchEvent."""

    def __init__(self, page, ident: int = 1):
        self.cdp = page.context.new_cdp_session(page)
        self.id = ident
        self.at = (0.0, 0.0)

    def _send(self, kind: str, points: list[dict]) -> None:
        self.cdp.send("Input.dispatchTouchEvent", {"type": kind, "touchPoints": points})

    def down(self, x: float, y: float) -> None:
        self.at = (x, y)
        self._send("touchStart", [{"x": x, "y": y, "id": self.id}])

    def move(self, x: float, y: float, steps: int = 8) -> None:
        x0, y0 = self.at
        for i in range(1, steps + 1):
            f = i / steps
            self._send(
                "touchMove", [{"x": x0 + f * (x - x0), "y": y0 + f * (y - y0), "id": self.id}]
            )
        self.at = (x, y)

    def up(self) -> None:
        self._send("touchEnd", [])


def stick_centre(page, name: str) -> tuple[float, float, float]:
    box = page.locator(f"[data-stick={name}]").bounding_box()
    return box["x"] + box["width"] / 2, box["y"] + box["height"] / 2, box["width"] / 2.5


@pytest.mark.timeout(120)
def test_touch_sticks_on_a_phone_fly_the_twin(twin_station, browser):
    app, url = twin_station
    twin = app.state.station.twin
    context = browser.new_context(
        viewport={"width": 844, "height": 390}, has_touch=True, is_mobile=True
    )
    page = context.new_page()
    page.goto(url + "/")
    page.wait_for_selector("#control-widget:not([hidden])", timeout=30_000)
    expect(page.locator("#touch-sticks")).to_be_hidden()  # only while the sticks are on
    page.locator("#ctl-toggle").tap()
    page.wait_for_function("window.fpvDebug.control.enabled === true", timeout=15_000)
    expect(page.locator("#touch-sticks")).to_be_visible()
    # The twin's controls wrap the header bar onto a second line: the front view still
    # fits the screen below it, its OSD menu button and camera readout with it.
    for part in ("#front-view", "#front-view .osd-menu-button", "#front-view .video-readout"):
        box = page.locator(part).bounding_box()
        assert box["y"] >= 0 and box["y"] + box["height"] <= 390, (part, box)
    left, right = Finger(page, 1), Finger(page, 2)

    # Arm by the documented gesture: left stick to the bottom-right corner, held.
    lx, ly, lhalf = stick_centre(page, "left")
    left.down(lx, ly)
    left.move(lx + 1.5 * lhalf, ly + 1.5 * lhalf)
    page.wait_for_function("window.fpvDebug.control.sticks.yaw === 1", timeout=15_000)
    assert page.evaluate("window.fpvDebug.control.sticks.throttle") == 0
    assert page.evaluate("window.fpvDebug.control.input") == "touch"
    assert wait_until(lambda: state(app).heartbeat.armed, timeout=10)
    left.up()
    # Yaw springs back, throttle stays down (a transmitter's throttle has no spring).
    page.wait_for_function("window.fpvDebug.control.sticks.yaw === 0", timeout=15_000)
    assert page.evaluate("window.fpvDebug.control.sticks.throttle") == 0

    # Throttle up to 0.9 and let go: it stays, and the twin climbs.
    left.down(lx, ly)
    left.move(lx, ly - 0.9 * 2 * lhalf)
    left.up()
    page.wait_for_function("window.fpvDebug.control.sticks.throttle > 0.85", timeout=15_000)
    assert wait_until(lambda: twin.pose().pos_enu_m[2] > 1.5, timeout=15)
    assert page.evaluate("window.fpvDebug.control.sticks.throttle") > 0.85
    # Back to the centre: hold the altitude.
    left.down(lx, ly)
    left.move(lx, ly + 0.4 * 2 * lhalf)
    left.up()
    page.wait_for_function(
        "Math.abs(window.fpvDebug.control.sticks.throttle - 0.5) < 0.02", timeout=3000
    )

    # The right stick forward: the twin flies forward; let go, and the stick centres.
    rx, ry, rhalf = stick_centre(page, "right")
    x0, y0 = twin.pose().pos_enu_m[:2]
    right.down(rx, ry)
    right.move(rx + 0.3 * rhalf, ry - 0.8 * rhalf)
    page.wait_for_function("window.fpvDebug.control.sticks.pitch > 0.7", timeout=15_000)
    assert page.evaluate("window.fpvDebug.control.sticks.roll") > 0.2
    assert wait_until(
        lambda: ((twin.pose().pos_enu_m[0] - x0) ** 2 + (twin.pose().pos_enu_m[1] - y0) ** 2) > 1.0,
        timeout=10,
    ), "the twin did not move on the right stick"
    right.up()
    page.wait_for_function(
        "window.fpvDebug.control.sticks.pitch === 0 && window.fpvDebug.control.sticks.roll === 0",
        timeout=3000,
    )
    assert page.locator("[data-stick=right]").get_attribute("data-y") == "0.00"
    # The station's RC channels show the sticks centred again (1500 us on pitch and roll).
    assert wait_until(lambda: state(app).rc.pwm_us[1] == 1500 and state(app).rc.pwm_us[0] == 1500)

    # A finger on the stick when the page loses focus: the sticks let go.
    right.down(rx, ry)
    right.move(rx, ry - 0.8 * rhalf)
    page.wait_for_function("window.fpvDebug.control.sticks.pitch > 0.5", timeout=15_000)
    page.evaluate("window.dispatchEvent(new Event('blur'))")
    page.wait_for_function("window.fpvDebug.control.sticks.pitch === 0", timeout=15_000)
    assert page.locator("[data-stick=right]").get_attribute("data-y") == "0.00"
    right.up()
    context.close()


# A gamepad cannot be plugged in here: navigator.getGamepads is replaced at the browser's
# boundary by one pad whose axes the test sets (window.__axes).
FAKE_PAD = """
window.__axes = [0, 0, 0, 0];
navigator.getGamepads = () => [{ id: "Test pad (STANDARD GAMEPAD)", connected: true,
  axes: window.__axes.slice(), buttons: [] }];
"""


def test_gamepad_panel_shows_live_axes_and_the_sticks_sent(twin_station, browser):
    app, url = twin_station
    page = browser.new_page()
    page.add_init_script(FAKE_PAD)
    sticks_on(page, url)
    page.click("#ctl-pad summary")
    bars = page.locator("#ctl-bars")
    expect(bars.locator("[data-bar=axis-3]")).to_have_count(1, timeout=15_000)
    # Right stick pushed forward (axis 3 negative on a standard pad): pitch forward.
    page.evaluate("window.__axes[3] = -0.5; window.__axes[0] = 0.25")
    expect(bars.locator("[data-bar=axis-3] td.num")).to_have_text("-0.50", timeout=15_000)
    expect(bars.locator("[data-bar=axis-0] td.num")).to_have_text("0.25")
    expect(bars.locator("[data-bar=sent-pitch] td.num")).to_have_text("0.50")
    expect(bars.locator("[data-bar=sent-yaw] td.num")).to_have_text("0.25")
    expect(bars.locator("[data-bar=sent-throttle] td.num")).to_have_text("0.50")
    # The bar is drawn from the centre to the value.
    rect = bars.locator("[data-bar=axis-3] rect")
    assert (rect.get_attribute("x"), rect.get_attribute("width")) == ("-0.5", "0.5")
    # What the panel says is what the station got (RC pitch channel off centre).
    assert wait_until(lambda: state(app).rc.pwm_us[1] != 1500, timeout=5)
    page.evaluate("window.__axes[3] = 0; window.__axes[0] = 0")
    expect(bars.locator("[data-bar=sent-pitch] td.num")).to_have_text("0.00", timeout=15_000)


def test_the_gamepad_flies_on_while_a_panel_in_the_page_has_focus(twin_station, browser):
    """A click into a frame of the page (the 3D panel's viewer is one) takes the keyboard's
    focus from the page, not the pilot's: the gamepad still flies."""
    app, url = twin_station
    page = browser.new_page()
    page.add_init_script(FAKE_PAD)
    sticks_on(page, url)
    page.evaluate(
        """() => document.body.append(Object.assign(document.createElement("iframe"),
             {id: "panel-frame", srcdoc: "<input id=i>"}))"""
    )
    page.frame_locator("#panel-frame").locator("#i").click()
    assert page.evaluate("document.activeElement.id") == "panel-frame"
    page.evaluate("window.__axes[3] = -0.8")  # right stick forward
    page.wait_for_function("window.fpvDebug.control.sticks.pitch === 0.8", timeout=15_000)
    assert wait_until(lambda: state(app).rc.pwm_us[1] != 1500, timeout=5)
    # A hidden tab still lets go (nobody watches the video then).
    page.evaluate(
        """() => { Object.defineProperty(document, "visibilityState", {value: "hidden"});
                   document.dispatchEvent(new Event("visibilitychange")); }"""
    )
    page.wait_for_function("window.fpvDebug.control.sticks.pitch === 0", timeout=15_000)


@pytest.mark.timeout(120)
def test_a_refused_disarm_is_shown_with_its_reason(twin_station, browser):
    app, url = twin_station
    page = browser.new_page()
    sticks_on(page, url)
    arm_and_climb(page, app.state.station)
    expect(page.locator("#toast")).to_be_hidden()
    page.click("#ctl-disarm")
    # The vehicle refuses (in the air): the toast says so and why, as does the OSD.
    toast = page.locator("#toast")
    expect(toast).to_be_visible(timeout=15_000)
    expect(toast).to_contain_text("disarm refused (DENIED)")
    expect(toast).to_contain_text("in the air")
    expect(page.locator("[data-osd=messages]")).to_contain_text("in the air", timeout=15_000)
    assert state(app).heartbeat.armed
    expect(page.locator("[data-osd=armed]")).to_have_text("ARMED")
