"""The FPV OSD (web/osd.js) over the pilot page's front camera, in real headless chromium
against a real station following the test MAVLink vehicle over real UDP."""

from __future__ import annotations

import math
import re
import time

import httpx
import numpy as np
import pytest
from playwright.sync_api import TimeoutError as PlaywrightTimeout
from playwright.sync_api import expect

from fpv_station.server.app import create_app
from tests.helpers import run_uvicorn, station_settings
from tests.mav_vehicle import MavVehicle
from tests.pages import overlap
from tests.stations import vehicle_station
from tests.twin_flights import twin_station_settings


@pytest.fixture
def station(tmp_path):
    with vehicle_station(tmp_path / "sessions", **{"link.link_lost_s": 1.0}) as station:
        yield station


def horizon_angle(page) -> float:
    """The drawn horizon line's angle (degrees, screen y down), from the canvas' pixels:
    the white pixels in two columns at a quarter of the width from each side (outside the
    pitch ladder, inside the horizon line)."""
    return page.evaluate(
        """() => {
        const c = document.querySelector('[data-osd=horizon]');
        const ctx = c.getContext('2d');
        const {width: W, height: H} = c;
        const img = ctx.getImageData(0, 0, W, H).data;
        // Mean bright row in two columns at +-20% of the width around the centre.
        const rowAt = (x) => { let sum = 0, n = 0;
          for (let y = 0; y < H; y++) { const i = (y * W + x) * 4;
            if (img[i + 3] > 200 && img[i] > 200 && img[i + 2] > 200) { sum += y; n++; } }
          return n ? sum / n : null; };
        const xl = Math.round(W * 0.25), xr = Math.round(W * 0.75);
        const yl = rowAt(xl), yr = rowAt(xr);
        if (yl === null || yr === null) return null;
        return Math.atan2(yr - yl, xr - xl) * 180 / Math.PI;
    }"""
    )


def test_osd_horizon_heading_values_messages_and_staleness(station, browser):
    vehicle, base = station
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    page.goto(base + "/")
    osd = lambda name: page.locator(f"[data-osd={name}]")  # noqa: E731
    expect(osd("mode")).to_have_text("POSCTL", timeout=30_000)
    for name in (
        "horizon",
        "heading",
        "altitude",
        "climb",
        "speed",
        "battery",
        "gps",
        "mode",
        "armed",
        "timer",
        "home",
        "link",
        "age",
        "warning",
        "messages",
    ):
        expect(osd(name)).to_have_count(1)

    # A level vehicle: a level horizon, centred.
    expect(osd("horizon")).to_have_attribute("data-roll", "0.0", timeout=15_000)
    level = horizon_angle(page)
    assert level is not None and abs(level) < 1.0

    # Roll 20 deg right: the horizon turns 20 deg the other way (counter-clockwise on the
    # screen); pitch 10 deg up moves it down, and the numbers say so.
    vehicle.roll_rad, vehicle.pitch_rad = math.radians(20), math.radians(10)
    expect(osd("horizon")).to_have_attribute("data-roll", "20.0", timeout=15_000)
    expect(osd("horizon")).to_have_attribute("data-pitch", "10.0")
    expect(osd("horizon")).to_have_text("roll 20° pitch 10°")
    angle = horizon_angle(page)
    assert angle is not None and abs(angle - (-20.0)) < 3.0, angle

    vehicle.yaw_rad = math.radians(93)
    expect(osd("heading")).to_have_text("093", timeout=15_000)
    expect(osd("heading")).to_have_attribute("data-heading", "93")

    vehicle.arm()
    vehicle.alt_m += 4.2
    vehicle.vx_mps, vehicle.vy_mps, vehicle.vz_mps = 3.0, 4.0, -1.5
    expect(osd("armed")).to_have_text("ARMED", timeout=15_000)
    expect(osd("altitude")).to_have_text("ALT 4.2 m", timeout=15_000)
    expect(osd("speed")).to_have_text("GS 5.0 m/s")
    expect(osd("climb")).to_have_text("VS +1.5 m/s")
    expect(osd("gps")).to_have_text("3D 12 sats")
    expect(osd("battery")).to_contain_text("12.3 V 87%")
    expect(osd("timer")).to_have_text(re.compile(r"00:(0[1-9]|[1-5]\d)"), timeout=15_000)
    expect(osd("home")).to_have_text("H 0 m")
    # At home the bearing is noise: a dot, no arrow. 20 m north, the arrow points home
    # (south, 180 deg) relative to the nose (093): 87 deg to the right.
    arrow, dot = osd("home").locator("path"), osd("home").locator("circle")
    expect(osd("home")).to_have_attribute("data-mark", "dot")
    expect(arrow).to_have_attribute("visibility", "hidden")
    expect(dot).to_have_attribute("visibility", "visible")
    vehicle.lat_deg += 20 / 111_320
    expect(osd("home")).to_have_text("H 20 m", timeout=15_000)
    expect(osd("home")).to_have_attribute("data-mark", "arrow")
    expect(osd("home")).to_have_attribute("data-bearing", "87")
    expect(arrow).to_have_attribute("visibility", "visible")
    expect(dot).to_have_attribute("visibility", "hidden")
    expect(osd("age")).to_have_text(re.compile(r"TLM 0\.\ds"))
    # (The test station's cameras have no signal: the OSD says so, and nothing else.)
    expect(osd("warning")).to_have_text("VIDEO STALE")

    # A STATUSTEXT reaches the messages line; an emergency warns. (How fast is the
    # benchmarks' figure: benchmarks/telemetry_latency.py.)
    vehicle.send_message(vehicle.mav.statustext_encode(2, b"Crash detected"))
    # (the newest of the last lines; the line before may be an earlier message)
    expect(osd("messages")).to_have_text(re.compile(r"(^|\n)CRIT Crash detected$"))
    expect(osd("warning")).to_contain_text("CRASH")

    # The vehicle goes silent: values grey out and show their age, LINK LOST warns.
    vehicle.silent = True
    expect(osd("altitude")).to_have_class(re.compile(r"\bosd-stale\b"), timeout=15_000)
    expect(osd("altitude")).to_have_text(re.compile(r"ALT 4\.2 m \(\d+s\)"))
    expect(osd("horizon")).to_have_class(re.compile(r"\bosd-stale\b"))
    expect(osd("warning")).to_contain_text("LINK LOST", timeout=15_000)
    expect(page.locator("#conn-status")).to_have_text("no telemetry", timeout=15_000)
    expect(page.locator("#v-rel-alt").locator("xpath=ancestor::tr")).to_have_class("stale")

    vehicle.silent = False
    expect(osd("altitude")).not_to_have_class(re.compile(r"\bosd-stale\b"), timeout=15_000)
    expect(page.locator("#conn-status")).to_have_text("live", timeout=15_000)


# Ink (opaque pixels) in the heading tape's label rows (its upper half): in the first and
# last two columns, in the first and last 8 % (where its end labels are), and anywhere.
TAPE_LABEL_INK = """() => {
  const c = document.querySelector('[data-osd=heading]');
  const {width: W, height: H} = c;
  const img = c.getContext('2d').getImageData(0, 0, W, Math.floor(H / 2)).data;
  let edge = 0, left = 0, right = 0, all = 0;
  for (let i = 3; i < img.length; i += 4) {
    if (img[i] < 100) continue;
    all++;
    const x = ((i - 3) / 4) % W;
    if (x < 2 || x >= W - 2) edge++;
    if (x < 0.08 * W) left++;
    if (x >= 0.92 * W) right++;
  }
  return {edge, left, right, all};
}"""


def test_heading_tape_draws_no_label_cut_at_its_ends(station, browser):
    """Heading 090: the tape spans 045..135, so NE and SE sit on its ends. A label cut in
    half there misreads (NE as "E", SE as "S"): they are drawn whole, inside the tape."""
    vehicle, base = station
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    page.goto(base + "/")
    vehicle.yaw_rad = math.radians(90)
    expect(page.locator("[data-osd=heading]")).to_have_attribute(
        "data-heading", "90", timeout=30_000
    )
    ink = page.evaluate(TAPE_LABEL_INK)
    assert ink["all"] > 0, "the tape drew no labels"
    assert ink["edge"] == 0, ink
    assert ink["left"] > 0 and ink["right"] > 0, ink  # NE and SE are there


def test_a_quiet_group_lends_no_freshness_to_its_old_value(station, browser):
    """VFR_HUD stops (another GCS on the link set its stream rate to 0) while
    GLOBAL_POSITION_INT goes on: speed and climb come from the position, fresh; VFR_HUD's
    last values are not shown as fresh because some other group still talks."""
    vehicle, base = station
    page = browser.new_page()
    page.goto(base + "/")
    osd = lambda name: page.locator(f"[data-osd={name}]")  # noqa: E731
    expect(osd("speed")).to_have_text("GS 0.0 m/s", timeout=30_000)
    vehicle.rates_hz["VFR_HUD"] = 0
    # VFR_HUD has gone quiet (its last one is half a second older than the newest state)
    # before the vehicle moves: its last values are those of a vehicle at rest.
    page.wait_for_function(
        "() => { const m = window.fpvDebug.feed.latest;"
        " return m.t_server_mono - m.state.vfr_hud.t_mono > 0.5; }",
        timeout=30_000,
    )
    vehicle.vx_mps, vehicle.vy_mps, vehicle.vz_mps = 3.0, 4.0, -1.5
    stale = re.compile(r"\bosd-stale\b")
    expect(osd("speed")).to_have_text("GS 5.0 m/s", timeout=15_000)
    expect(osd("climb")).to_have_text("VS +1.5 m/s")
    for name in ("speed", "climb"):
        expect(osd(name)).not_to_have_class(stale)
    # The flight state table says the same.
    expect(page.locator("#v-ground-speed")).to_have_text("5.0")
    expect(page.locator("#v-climb")).to_have_text("1.5")
    for cell in ("#v-ground-speed", "#v-climb"):
        expect(page.locator(cell).locator("xpath=ancestor::tr")).not_to_have_class("stale")


def test_a_page_opened_mid_flight_shows_the_running_timer_and_the_vehicles_mah(station, browser):
    """The flight timer and mAh used come from the station's state, not from what a page
    saw: goggles reloaded (or a second laptop joining) mid-flight show the flight's timer
    and the autopilot's own mAh count from their first frame."""
    vehicle, base = station
    first = browser.new_page()
    first.goto(base + "/")
    osd1 = lambda name: first.locator(f"[data-osd={name}]")  # noqa: E731
    expect(osd1("armed")).to_have_text("DISARMED", timeout=30_000)
    expect(osd1("timer")).to_have_text("00:00")
    vehicle.consumed_mah = 1500.0  # the pack gave some on an earlier flight (4.5 A now)
    vehicle.arm()
    # Some seconds into the flight, as the page open since before arming counts them.
    expect(osd1("timer")).to_have_text(re.compile(r"00:(0[3-9]|[1-5]\d)"), timeout=30_000)
    flown_s = int(osd1("timer").text_content().split(":")[1])

    second = browser.new_page()
    second.goto(base + "/")
    # Its first frame that shows the vehicle armed (timer and battery read with it).
    timer, battery = second.wait_for_function(
        """() => { const q = (n) => document.querySelector(`[data-osd=${n}]`);
        return q("armed") && q("armed").textContent === "ARMED"
          && [q("timer").textContent, q("battery").textContent]; }""",
        timeout=30_000,
    ).json_value()
    mm, ss = (int(x) for x in timer.split(":"))
    # At least the time the first page had counted (less a second of rounding and delivery).
    assert 60 * mm + ss >= flown_s - 1, (timer, flown_s)
    shown_mah = int(re.fullmatch(r"12\.3 V 87% (\d+) mAh", battery).group(1))
    assert 1500 <= shown_mah <= vehicle.consumed_mah + 1, (battery, vehicle.consumed_mah)
    # Both pages show the same: the timer runs on in each (it holds after disarming).
    vehicle.disarm()
    expect(osd1("armed")).to_have_text("DISARMED", timeout=15_000)
    expect(second.locator("[data-osd=armed]")).to_have_text("DISARMED", timeout=15_000)
    held = osd1("timer").text_content()
    assert held != "00:00"
    expect(second.locator("[data-osd=timer]")).to_have_text(held)
    time.sleep(1.5)  # held, not running: the same text a while later
    expect(osd1("timer")).to_have_text(held)


# The pitch ladder's reach as drawn (the horizon canvas' data-reach) and where it should
# be: from the centre to the heading tape's foot, or the top of the picture without the
# tape; and the tape canvas' size against its box (both in canvas pixels).
LADDER_REACH = """() => {
  const h = document.querySelector('[data-osd=horizon]');
  const t = document.querySelector('[data-osd=heading]');
  const foot = t.hidden ? 0
    : (t.getBoundingClientRect().bottom - h.getBoundingClientRect().top) * devicePixelRatio;
  return {reach: Number(h.dataset.reach), expected: h.height / 2 - foot,
    tape: [t.width, Math.round(t.clientWidth * devicePixelRatio)]};
}"""


def ladder_reach(page) -> dict:
    """LADDER_REACH once the drawn reach is where it should be (a hang guard: a stale
    reach stays put, and the assertion then shows both)."""
    try:
        page.wait_for_function(
            f"() => {{ const r = ({LADDER_REACH})(); return Math.abs(r.reach - r.expected) <= 2; }}",
            timeout=10_000,
        )
    except PlaywrightTimeout:
        pass
    got = page.evaluate(LADDER_REACH)
    assert abs(got["reach"] - got["expected"]) <= 2, got
    return got


def test_osd_elements_switch_off_and_stay_off(station, browser):
    """Switched off in the menu, an element stays off over a reload. The heading tape
    switched off or on moves the pitch ladder's reach with it, without a resize."""
    vehicle, base = station
    page = browser.new_page()
    page.goto(base + "/")
    expect(page.locator("[data-osd=mode]")).to_have_text("POSCTL", timeout=30_000)
    under_tape = ladder_reach(page)["reach"]
    page.locator(".osd-menu-button").click()
    page.locator("[data-osd-toggle=battery]").uncheck()
    page.locator("[data-osd-toggle=heading]").uncheck()
    expect(page.locator("[data-osd=battery]")).to_be_hidden()
    expect(page.locator("[data-osd=heading]")).to_be_hidden()
    assert ladder_reach(page)["reach"] > under_tape
    page.reload()
    expect(page.locator("[data-osd=mode]")).to_have_text("POSCTL", timeout=30_000)
    expect(page.locator("[data-osd=battery]")).to_be_hidden()
    expect(page.locator("[data-osd=gps]")).to_be_visible()
    ladder_reach(page)
    # Off since the page opened, then on: the tape gets its size, the ladder stops under it.
    page.locator(".osd-menu-button").click()
    page.locator("[data-osd-toggle=heading]").check()
    expect(page.locator("[data-osd=heading]")).to_be_visible()
    back = ladder_reach(page)
    assert abs(back["reach"] - under_tape) <= 1, back
    assert back["tape"][0] == back["tape"][1] > 0, back


# Pairs of visible OSD texts, the OSD button and the camera readout in `view` whose boxes
# overlap by more than a pixel (the horizon and the centre warning may lie over others).
OVERLAPS = """(view) => {
  const items = [...document.querySelectorAll(
    `${view} .osd-item:not(canvas):not(.osd-warning):not(:empty), ${view} .osd-menu-button,`
    + ` ${view} .video-readout`)].filter((e) => e.offsetParent !== null);
  const out = [];
  items.forEach((a, i) => items.slice(i + 1).forEach((b) => {
    const r = a.getBoundingClientRect(), q = b.getBoundingClientRect();
    if (r.left < q.right - 1 && q.left < r.right - 1 && r.top < q.bottom - 1 && q.top < r.bottom - 1)
      out.push([a.className, a.textContent, b.className, b.textContent]);
  }));
  return out;
}"""


@pytest.mark.parametrize("size", [(1280, 720), (1920, 1080)])
def test_goggles_fill_the_screen_with_the_osd_and_no_scrollbars(station, browser, size):
    vehicle, base = station
    w, h = size
    page = browser.new_page(viewport={"width": w, "height": h})
    page.goto(base + "/goggles.html")
    expect(page.locator("[data-osd=mode]")).to_have_text("POSCTL", timeout=30_000)
    vehicle.yaw_rad = math.radians(45)
    expect(page.locator("[data-osd=heading]")).to_have_text("045", timeout=15_000)
    box = page.evaluate(
        """() => { const r = document.querySelector('#front-view .video-stream').getBoundingClientRect();
        const d = document.documentElement;
        return {area: r.width * r.height, view: innerWidth * innerHeight,
                sw: d.scrollWidth, cw: d.clientWidth, sh: d.scrollHeight, ch: d.clientHeight,
                chrome: document.querySelectorAll('#toolbar, header').length}; }"""
    )
    assert box["area"] >= 0.9 * box["view"], box
    assert box["sw"] <= box["cw"] and box["sh"] <= box["ch"], box
    assert box["chrome"] == 0
    assert page.evaluate("getComputedStyle(document.body).backgroundColor") == "rgb(0, 0, 0)"
    # Nothing written over anything else: the OSD's text elements, its menu button and the
    # camera's readout each have their own place.
    clashes = page.evaluate(OVERLAPS, "#front-view")
    assert clashes == [], clashes

    bottom = page.locator("#bottom-view")
    expect(bottom).to_be_hidden()
    page.keyboard.press("b")
    expect(bottom).to_be_visible()
    expect(bottom.locator(".video-stream")).to_have_count(1)
    page.keyboard.press("b")
    expect(bottom).to_be_hidden()

    # Side-by-side stereo: two halves, each with its own OSD; off again stops the second.
    page.keyboard.press("s")
    right = page.locator("#front-view-right")
    expect(right).to_be_visible()
    expect(right.locator("[data-osd=heading]")).to_have_text("045", timeout=15_000)
    halves = page.evaluate(
        """() => ['#front-view', '#front-view-right'].map(
            (s) => document.querySelector(s).getBoundingClientRect().width)"""
    )
    assert all(abs(wd - w / 2) <= 1 for wd in halves), halves
    page.keyboard.press("s")
    expect(right).to_be_hidden()
    # The hidden eye's OSD draws nothing (it drew every frame); on again, it draws again.
    frames = lambda: page.evaluate("fpvDebug.osdRight.stats.frames")  # noqa: E731
    drawn = frames()
    page.wait_for_timeout(1000)
    assert frames() == drawn
    page.keyboard.press("s")
    expect(right).to_be_visible()
    page.wait_for_function("(n) => fpvDebug.osdRight.stats.frames > n", arg=drawn, timeout=15_000)


def test_goggles_stereo_eyes_switch_osd_elements_together(station, browser):
    """An element switched off in the menu goes from both eyes of side-by-side stereo: the
    right eye's OSD is no second, unswitchable copy."""
    vehicle, base = station
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    page.goto(base + "/goggles.html")
    expect(page.locator("[data-osd=mode]").first).to_have_text("POSCTL", timeout=30_000)
    page.keyboard.press("s")
    eyes = [
        page.locator(f"{view} [data-osd=battery]") for view in ("#front-view", "#front-view-right")
    ]
    for battery in eyes:
        expect(battery).to_be_visible(timeout=15_000)
    page.keyboard.press("o")
    page.locator("#front-view [data-osd-toggle=battery]").uncheck()
    for battery in eyes:
        expect(battery).to_be_hidden()
    page.locator("#front-view [data-osd-toggle=battery]").check()
    for battery in eyes:
        expect(battery).to_be_visible()
    # An eye is small: nose up or down, the pitch ladder draws nothing over the heading tape.
    horizon = page.locator("#front-view [data-osd=horizon]")
    for pitch in (2, 4, 6, 8, -4, -8):
        vehicle.pitch_rad = math.radians(pitch)
        expect(horizon).to_have_attribute("data-pitch", f"{pitch:.1f}")
        assert page.evaluate(LADDER_INK_ON_TAPE) == 0, pitch
    vehicle.pitch_rad = 0.0


# Opaque pixels of the left eye's horizon canvas inside the heading tape's box.
LADDER_INK_ON_TAPE = """() => {
  const c = document.querySelector('#front-view [data-osd=horizon]');
  const t = document.querySelector('#front-view [data-osd=heading]').getBoundingClientRect();
  const b = c.getBoundingClientRect(), k = c.width / b.width;
  const x = Math.round((t.left - b.left) * k), y = Math.round((t.top - b.top) * k);
  const img = c.getContext('2d').getImageData(x, y, Math.round(t.width * k), Math.round(t.height * k));
  let ink = 0;
  for (let i = 3; i < img.data.length; i += 4) if (img.data[i] > 100) ink++;
  return ink;
}"""


def test_goggles_show_the_task_step_as_an_osd_line(station, browser):
    vehicle, base = station
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    page.goto(base + "/goggles.html")
    expect(page.locator("[data-osd=mode]")).to_have_text("POSCTL", timeout=30_000)
    tasks = page.evaluate("fetch('/api/task').then(r => r.json())")
    if not tasks["tasks"]:
        pytest.skip("no tasks in the station's scene")
    first_task = tasks["tasks"][0]["id"]
    reply = page.request.post(base + "/api/task", data={"task_id": first_task})
    assert reply.ok, reply.text()
    page.reload()
    # What to do next, not the step's name as done ("TASK Armed" while disarmed).
    expect(page.locator("[data-osd=task]")).to_have_text("next: arm", timeout=30_000)
    # In the lines' column (under the latency's line when there is one), not over it.
    line, column = (page.locator(s).bounding_box() for s in ("[data-osd=task]", ".osd-lines"))
    assert column["height"] >= line["height"] > 0, (line, column)
    # Side-by-side stereo: the right eye shows the step too, from the moment it appears.
    page.keyboard.press("s")
    right = page.locator("#front-view-right [data-osd=task]")
    expect(right).to_have_text("next: arm", timeout=15_000)
    vehicle.arm()
    expect(page.locator("#front-view [data-osd=task]")).to_have_text(
        "next: take off", timeout=30_000
    )
    expect(right).to_have_text("next: take off", timeout=15_000)


@pytest.mark.parametrize("size", [(390, 844), (844, 390)])
def test_pilot_page_has_no_horizontal_scroll_on_a_phone(station, browser, size):
    vehicle, base = station
    page = browser.new_page(viewport={"width": size[0], "height": size[1]})
    page.goto(base + "/")
    expect(page.locator("[data-osd=mode]")).to_have_text("POSCTL", timeout=30_000)
    sw, cw = page.evaluate(
        "[document.documentElement.scrollWidth, document.documentElement.clientWidth]"
    )
    assert sw <= cw, (sw, cw)
    assert page.evaluate(OVERLAPS, "#front-view") == []
    page.locator("#bottom-view").scroll_into_view_if_needed()
    expect(page.locator("#bottom-view .video-stream")).to_be_in_viewport()


def test_not_recording_shows_while_armed_without_a_recording(tmp_path, browser):
    """The station cannot create its sessions folder when the vehicle arms (a file is in
    its way): the arming's start is refused, and while the vehicle is armed the OSD shows
    a red NOT RECORDING. Once the folder can be made the retry records the flight and
    the badge goes; disarmed, nothing is missing."""
    blocked = tmp_path / "sessions"
    blocked.write_text("not a folder")
    with MavVehicle("udp") as vehicle:
        settings = station_settings(
            vehicle.station_source, blocked, **{"recording.auto_record_on_arm": True}
        )
        with run_uvicorn(create_app(settings)) as base:
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(base + "/")
            badge = page.locator("[data-osd=recording]")
            expect(page.locator("[data-osd=mode]")).to_have_text("POSCTL", timeout=30_000)
            expect(badge).to_have_text("")
            vehicle.arm()
            expect(badge).to_have_text("NOT RECORDING", timeout=15_000)
            expect(badge).to_have_class(re.compile(r"\bosd-bad\b"))
            assert page.evaluate(OVERLAPS, "#front-view") == []
            recording = httpx.get(f"{base}/api/recording").json()
            assert not recording["recording"] and "Cannot record in" in recording["last_error"]
            assert recording["not_recording"] and recording["armed_unrecorded_s"] >= 1.0

            blocked.unlink()
            # A hang guard over the recorder's retry, whose wait doubles up to 30 s while
            # starts fail (a loaded machine has had time for several).
            expect(badge).to_have_text("", timeout=60_000)
            expect(badge).not_to_have_class(re.compile(r"\bosd-bad\b"))
            recording = httpx.get(f"{base}/api/recording").json()
            assert recording["recording"] and recording["trigger"] == "retry", recording
            vehicle.disarm()
            expect(page.locator("[data-osd=armed]")).to_have_text("DISARMED", timeout=15_000)
            expect(badge).to_have_text("")


# The drawn horizon's row in the horizon canvas (mean of its white pixels in the columns at a
# quarter and three quarters of the width, where only the horizon line is drawn), with the
# canvas' size.
HORIZON_ROW = """() => {
  const c = document.querySelector('[data-osd=horizon]');
  const {width: W, height: H} = c;
  const img = c.getContext('2d').getImageData(0, 0, W, H).data;
  const rowAt = (x) => { let sum = 0, n = 0;
    for (let y = 0; y < H; y++) { const i = (y * W + x) * 4;
      if (img[i + 3] > 200 && img[i] > 200 && img[i + 2] > 200) { sum += y; n++; } }
    return n ? sum / n : null; };
  const yl = rowAt(Math.round(W * 0.25)), yr = rowAt(Math.round(W * 0.75));
  return {W, H, row: yl === null || yr === null ? null : (yl + yr) / 2};
}"""


def rendered_horizon_row(frame) -> float:
    """The sky/ground boundary's row in a twin frame at the columns a quarter and three
    quarters across: the last sky pixel of each column (sky is not seen below the horizon;
    obstacles and the net only hide some of it), the lowest in a small band of columns."""
    from fpv_station.twin.render import SKY_BGR

    height, width = frame.shape[:2]
    sky = (frame == np.array(SKY_BGR, np.uint8)).all(axis=2)
    rows = np.arange(height)[:, None]
    last_sky = np.where(sky, rows, -1).max(axis=0) + 1.0  # per column
    bands = [last_sky[int(width * q) - 8 : int(width * q) + 8].max() for q in (0.25, 0.75)]
    return float(np.mean(bands))


# A hang guard: a twin flown by a page's sticks, its camera and Chromium took over 120 s
# beside a full suite and two CPU hogs.
@pytest.mark.timeout(300)
def test_osd_horizon_lies_on_the_twins_rendered_horizon_in_a_level_hover(tmp_path, browser):
    """The twin's front camera looks 15 degrees above the nose, its picture ~84 degrees
    high: the OSD draws the horizon with the optics the station declares for it, so in a
    level hover the drawn horizon lies on the rendered one (within 2 degrees), not on the
    picture's centre."""
    from tests.helpers import arm_and_climb, sticks_on

    # The twin at twice real time, flown by the page's sticks: no recording on arming. The
    # front camera as the twin declares it, at half its rate; no bottom camera.
    settings = twin_station_settings(
        tmp_path,
        {
            "twin.realtime_factor": 2.0,
            "recording.auto_record_on_arm": False,
            "cameras.front.fps": 15.0,
            "cameras.bottom.spec": "none",
        },
    )
    app = create_app(settings)
    station = None
    with run_uvicorn(app) as base:
        station = app.state.station
        # A hang guard: the twin builds its textures as the station starts, and on a
        # loaded box that holds the interpreter for seconds (httpx's default is 5 s).
        cameras = httpx.get(base + "/api/cameras", timeout=60).json()["cameras"]
        front = next(c for c in cameras if c["name"] == "front")
        tilt, vfov = front["tilt_up_deg"], front["vfov_deg"]
        model = station.twin.optics("front")
        assert (tilt, vfov) == (model.tilt_up_deg, model.vfov_deg)
        assert tilt == pytest.approx(15.0) and vfov == pytest.approx(83.6, abs=0.1)

        page = browser.new_page(viewport={"width": 1280, "height": 800})
        sticks_on(page, base)
        arm_and_climb(page, station, height_m=1.5)
        # The OSD draws with the camera's declared field of view (its horizon's data-vfov).
        page.wait_for_function(
            "(vfov) => Math.abs(document.querySelector('[data-osd=horizon]').dataset.vfov - vfov)"
            " < 0.1",
            arg=vfov,
            timeout=60_000,
        )
        # Level: the hover has settled (the OSD's own roll and pitch near zero).
        page.wait_for_function(
            """() => { const d = document.querySelector('[data-osd=horizon]').dataset;
            return Math.abs(+d.roll) < 1 && Math.abs(+d.pitch) < 1; }""",
            timeout=30_000,
        )
        drawn = page.evaluate(HORIZON_ROW)
        frame = station.twin.render("front")

    # Both rows as angles below the picture's centre, through the declared field of view.
    # The picture is shown whole (object-fit: contain) and centred in the canvas.
    ih, iw = frame.shape[:2]
    f_frame = (ih / 2) / math.tan(math.radians(vfov) / 2)
    rendered_deg = math.degrees(math.atan((rendered_horizon_row(frame) - ih / 2) / f_frame))
    pic_h = ih * min(drawn["W"] / iw, drawn["H"] / ih)
    f_canvas = (pic_h / 2) / math.tan(math.radians(vfov) / 2)
    assert drawn["row"] is not None, "no horizon drawn"
    drawn_deg = math.degrees(math.atan((drawn["row"] - drawn["H"] / 2) / f_canvas))
    assert rendered_deg == pytest.approx(15.0, abs=3.0)  # the camera's tilt, level
    assert abs(drawn_deg - rendered_deg) < 2.0, (drawn_deg, rendered_deg)
    # ... as the OSD says it drew it.
    drawn_with = page.locator("[data-osd=horizon]")
    assert (drawn_with.get_attribute("data-tilt"), drawn_with.get_attribute("data-vfov")) == (
        "15.0",
        f"{vfov:.1f}",
    )
    print(f"horizon: rendered {rendered_deg:.2f} deg, drawn {drawn_deg:.2f} deg below centre")


# A laptop, and a phone on its side, whose header bar is a narrow column beside the video.
@pytest.mark.parametrize("size", [(1280, 720), (844, 390)])
def test_link_lost_banner_leaves_the_osd_uncovered(station, browser, size):
    """The vehicle goes silent: the page's LINK LOST banner shows, and it lies over no part
    of the front view, whose OSD says LINK LOST itself."""
    vehicle, base = station
    w, h = size
    page = browser.new_page(viewport={"width": w, "height": h})
    page.goto(base + "/")
    expect(page.locator("[data-osd=mode]")).to_have_text("POSCTL", timeout=30_000)
    vehicle.silent = True
    banner = page.locator("#link-banner")
    expect(banner).to_be_visible(timeout=30_000)
    expect(banner).to_contain_text("LINK LOST")
    expect(page.locator("[data-osd=warning]")).to_contain_text("LINK LOST")
    view = page.locator("#front-view").bounding_box()
    assert not overlap(banner.bounding_box(), view), (banner.bounding_box(), view)


def test_a_station_that_is_down_is_not_reported_as_gps_lost(tmp_path, browser):
    """The station stops while the page is open: the OSD says the station is unreachable.
    Its last GPS fix ages like every other group, but no GPS was lost: no GPS LOST."""
    with MavVehicle("udp") as vehicle:
        settings = station_settings(vehicle.station_source, tmp_path / "sessions")
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        with run_uvicorn(create_app(settings)) as base:
            page.goto(base + "/", timeout=90_000)  # a hang guard: once over 30 s at load 17
            expect(page.locator("[data-osd=gps]")).to_have_text("3D 12 sats", timeout=30_000)
        warning, gps = page.locator("[data-osd=warning]"), page.locator("[data-osd=gps]")
        # The last fix is well past the GPS's lost age (3 s).
        expect(gps).to_have_text(re.compile(r"\(([4-9]|\d\d+)s\)"), timeout=30_000)
        expect(warning).not_to_contain_text("GPS LOST")
        expect(warning).to_contain_text("STATION UNREACHABLE")
        expect(warning).not_to_contain_text("LINK LOST")
