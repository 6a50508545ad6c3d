"""Controls a newcomer finds, in headless Chromium against the real twin: the `?` legend
says how the sticks are turned on and the arming gesture turns them on; the goggles' OSD
menu with Disarm, Land and RTL shows in both eyes in stereo; on a phone on its side the
video takes half the screen and the touch sticks cover no control; and while one pilot
page has the sticks, the sessions page lands the twin and disarms it in flight (after
asking), a second pilot page is told that the sticks are taken, and every refusal is a
toast."""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

from fpv_station.server.app import create_app
from tests.helpers import PICTURE_WIDTH, run_uvicorn, wait_until
from tests.twin_flights import NO_CAMERAS, NO_ONBOARD_LOG, twin_station_settings


def state(app):
    latest = app.state.station.state.get()
    return latest.value if latest else None


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    settings = twin_station_settings(
        tmp_path_factory.mktemp("sessions"),
        {
            "recording.auto_record_on_arm": False,
            **NO_CAMERAS,
            **NO_ONBOARD_LOG,
        },
    )
    app = create_app(settings)
    with run_uvicorn(app) as url:
        assert wait_until(lambda: state(app) and state(app).gps.fix_type == 3, timeout=30)
        yield app, url


def click_and_answer(page, locator, accept: bool) -> str:
    """Click, and answer the question the click asks (after a request: the events are
    read while Playwright waits); returns the question."""
    asked: list[str] = []

    def answer(dialog) -> None:
        asked.append(dialog.message)
        if accept:
            dialog.accept()
        else:
            dialog.dismiss()

    page.once("dialog", answer)
    locator.click()
    for _ in range(300):  # a hang guard: 30 s
        if asked:
            return asked[0]
        page.wait_for_timeout(100)
    raise AssertionError("no question asked")


def armed(app) -> bool:
    s = state(app)
    return bool(s and s.heartbeat.armed)


@pytest.mark.timeout(120)
def test_legend_says_how_and_the_arming_gesture_turns_the_sticks_on(station, browser):
    app, url = station
    page = browser.new_page()
    page.goto(url + "/")
    page.wait_for_selector("#control-widget:not([hidden])", timeout=30_000)
    page.keyboard.press("?")
    legend = page.locator("#key-legend")
    expect(legend).to_be_visible()
    expect(legend).to_contain_text("Sticks: off")
    expect(legend).to_contain_text("turns the sticks on")
    page.keyboard.press("Escape")
    expect(legend).to_be_hidden()
    assert page.evaluate("window.fpvDebug.control.enabled") is False
    # The gesture with the sticks off: they come on, and the keys still held arm.
    page.keyboard.down("ArrowDown")
    page.keyboard.down("KeyE")
    page.wait_for_function("window.fpvDebug.control.enabled === true", timeout=15_000)
    assert wait_until(lambda: armed(app), timeout=15), "the gesture did not arm"
    page.keyboard.up("KeyE")
    page.keyboard.down("KeyQ")  # down + Q: disarm on the ground
    assert wait_until(lambda: not armed(app), timeout=15), "the gesture did not disarm"
    page.keyboard.up("KeyQ")
    page.keyboard.up("ArrowDown")
    page.close()


def test_goggles_stereo_menu_in_both_eyes_with_the_emergency_buttons(station, browser):
    _, url = station
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    page.goto(url + "/goggles.html")
    page.wait_for_selector(".osd-menu .emergency:not([hidden])", state="attached", timeout=30_000)
    page.keyboard.press("s")
    expect(page.locator("#front-view-right")).to_be_visible()
    page.keyboard.press("o")
    menus = page.locator(".osd-menu")
    expect(menus).to_have_count(2)
    for eye in ("#front-view", "#front-view-right"):
        menu = page.locator(f"{eye} .osd-menu")
        expect(menu).to_be_visible()
        expect(menu.locator("[data-emergency=land]")).to_be_visible()
    # The menu button of either eye closes both.
    page.locator("#front-view-right .osd-menu-button").click()
    expect(menus.nth(0)).to_be_hidden()
    expect(menus.nth(1)).to_be_hidden()
    page.close()


# Each visible control's centre: is what is drawn there the control itself?
CONTROLS_ON_TOP = """() => [...document.querySelectorAll(
    'button, select, a[href], input, summary')].filter((e) => e.checkVisibility()
    && !e.closest('#touch-sticks')).map((e) => {
  const r = e.getBoundingClientRect();
  if (r.bottom < 0 || r.top > innerHeight) return null; // below the fold: scrolled to
  const hit = document.elementFromPoint(r.x + r.width / 2, r.y + r.height / 2);
  return e.contains(hit) ? null : `${e.outerHTML.slice(0, 60)} under ${hit && hit.outerHTML.slice(0, 60)}`;
}).filter((x) => x)"""


def test_phone_landscape_video_takes_half_the_screen_and_sticks_cover_no_control(station, browser):
    _, url = station
    w, h = 915, 412  # a large phone: wider than the header bar's 900 px wrapping limit
    context = browser.new_context(
        viewport={"width": w, "height": h}, is_mobile=True, has_touch=True
    )
    page = context.new_page()
    page.goto(url + "/")
    page.wait_for_selector("#control-widget:not([hidden])", timeout=30_000)
    page.locator("#ctl-toggle").tap()
    page.wait_for_function("window.fpvDebug.control.held === true", timeout=15_000)
    expect(page.locator("#touch-sticks")).to_be_visible()
    front = page.locator("#front-view").bounding_box()
    # The picture as drawn (its frames' shape contained in the view), not the view's box.
    picture, _ = page.evaluate(PICTURE_WIDTH, "front-view")
    shape = page.evaluate(
        "(c => c.height / c.width)(document.querySelector('#front-view .video-stream'))"
    )
    assert picture * picture * shape >= 0.5 * w * h, (picture, shape, front)
    assert page.evaluate("document.documentElement.scrollWidth") <= w  # no sideways scrolling
    covered = page.evaluate(CONTROLS_ON_TOP)
    assert covered == [], covered
    # Each stick lies over the picture.
    for stick in ("left", "right"):
        box = page.locator(f".touch-stick-{stick}").bounding_box()
        assert (
            box["x"] >= front["x"] - 1
            and box["x"] + box["width"] <= front["x"] + front["width"] + 1
        )
    context.close()


@pytest.mark.timeout(180)
def test_emergency_from_another_page_while_one_has_the_sticks(station, browser):
    app, url = station
    twin = app.state.station.twin
    pilot = browser.new_page()
    pilot.goto(url + "/")
    pilot.wait_for_selector("#control-widget:not([hidden])", timeout=30_000)
    pilot.click("#ctl-toggle")
    pilot.wait_for_function("window.fpvDebug.control.held === true", timeout=15_000)
    pilot.click("#ctl-arm")
    assert wait_until(lambda: armed(app), timeout=15), "the twin did not arm"
    expect(pilot.locator("#toast")).to_contain_text("arm: done")
    pilot.keyboard.down("ArrowUp")
    assert wait_until(lambda: twin.pose().pos_enu_m[2] > 6.0, timeout=30)
    pilot.keyboard.up("ArrowUp")

    # A second pilot page: the sticks are taken, and its Arm is refused, visibly.
    second = browser.new_page()
    second.goto(url + "/")
    second.wait_for_selector("#control-widget:not([hidden])", timeout=30_000)
    second.click("#ctl-toggle")
    expect(second.locator("#ctl-toggle")).to_have_text("Sticks: taken")
    second.click("#ctl-arm")
    expect(second.locator("#toast")).to_contain_text("arm: another page has the sticks")

    # The sessions page: RTL and Land are carried out, though another page has the sticks.
    sessions = browser.new_page()
    sessions.goto(url + "/sessions.html")
    rtl = sessions.locator("#toolbar .emergency [data-emergency=rtl]")
    expect(rtl).to_be_visible(timeout=30_000)
    rtl.click()
    expect(sessions.locator("#toast")).to_contain_text("rtl: done")
    # Home is where it took off: it descends there at once, in Return mode (AUTO.RTL).
    assert wait_until(lambda: state(app).heartbeat.mode == "RTL", timeout=15)
    pilot.locator("#ctl-mode").select_option("POSCTL")
    assert wait_until(lambda: state(app).heartbeat.mode == "POSCTL", timeout=15)
    land = sessions.locator("#toolbar .emergency [data-emergency=land]")
    land.click()
    expect(sessions.locator("#toast")).to_contain_text("land: done")
    assert wait_until(lambda: state(app).heartbeat.mode == "LAND", timeout=15)
    pilot.locator("#ctl-mode").select_option("POSCTL")  # the pilot takes over again
    assert wait_until(lambda: state(app).heartbeat.mode == "POSCTL", timeout=15)
    assert twin.pose().pos_enu_m[2] > 1.0
    # Disarm in flight asks first: declined, nothing is sent.
    disarm = sessions.locator("#toolbar [data-emergency=disarm]")
    asked = click_and_answer(sessions, disarm, accept=False)
    assert "in flight" in asked
    expect(sessions.locator("#toast")).to_be_hidden(timeout=30_000)  # the land toast went
    assert armed(app)
    # Accepted: the motors stop in the air.
    click_and_answer(sessions, disarm, accept=True)
    assert wait_until(lambda: not armed(app), timeout=15), "the emergency disarm was not done"
    expect(sessions.locator("#toast")).to_contain_text("disarm: done")
    for page in (pilot, second, sessions):
        page.close()
