"""The OSD runs on the source's clock: on a replay at x0.25 or x4 its ages, staleness,
LINK LOST and flight timer are the log's, and they stand still when the log ends (real
headless chromium, a real station replaying a real .tlog through its `replay:` source).

Each log is an armed vehicle at a real autopilot's rates (tests/shaped_tlog) with fades,
stretches where nothing arrives. The page records every change of the OSD with the
source time of the newest message it had (window.fpvDebug.feed.latest.t_server_mono), and the
test compares that record with the log."""

from __future__ import annotations

import re

import httpx
import pytest
from playwright.sync_api import expect

from fpv_station.server.app import create_app
from tests import shaped_tlog
from tests.helpers import run_uvicorn, station_settings, wait_until

T0 = 1_700_000_000.0


def armed_log(path, end_s: float, fades: list[tuple[float, float]]):
    """An armed PX4 vehicle (armed from its first heartbeat at 0 s) for `end_s` seconds;
    nothing arrives within each (start, end) of `fades`."""
    log = shaped_tlog.Shaper(t0=T0)
    ap = log.sender(1, 1)
    for tick in range(int(end_s * 50)):
        t = tick / 50
        if any(a <= t < b for a, b in fades):
            continue
        for msg in shaped_tlog.autopilot_messages(ap.mav, t):
            if msg.get_type() == "HEARTBEAT":
                msg = shaped_tlog.heartbeat(ap.mav, armed=True)
            log.emit(ap, t, msg)
    return log.write(path)


# Every change of the OSD's texts and classes and of the page's LINK LOST banner, with
# the source time of the page's newest message then (seconds of the log).
RECORD = """(t0) => {
  window.__osd = [];
  const root = document.querySelector('#front-view .osd');
  const banner = document.querySelector('#link-banner');
  const note = () => {
    const m = window.fpvDebug.feed.latest;
    if (!m) return;
    const q = (n) => root.querySelector(`[data-osd=${n}]`);
    window.__osd.push({t: m.t_server_mono - t0, timer: q('timer').textContent,
      altitude: q('altitude').className, mode: q('mode').className,
      warning: q('warning').textContent, age: q('age').textContent,
      banner: !banner.hidden,
      detail: document.querySelector('#link-banner-detail').textContent});
  };
  for (const node of [root, banner]) {
    new MutationObserver(note).observe(node, {subtree: true, childList: true,
      characterData: true, attributes: true, attributeFilter: ['class', 'hidden']});
  }
}"""


def replay_station(path, speed: str, tmp_path, **overrides):
    settings = station_settings(f"replay:{path}?speed={speed}", tmp_path / "sessions", **overrides)
    return run_uvicorn(create_app(settings))


def open_osd(browser, base, ready_before_s: float):
    """The pilot page, recording (RECORD) from the moment its OSD shows the armed
    vehicle, which must be before `ready_before_s` of the log; and that moment."""
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    page.goto(base + "/")
    expect(page.locator("[data-osd=armed]")).to_have_text("ARMED", timeout=30_000)
    page.evaluate(RECORD, T0)
    start = page.evaluate("window.fpvDebug.feed.latest.t_server_mono") - T0
    assert start < ready_before_s, f"the page was ready at {start:.1f} s of the log"
    return page, start


def record_until(page, t_s: float) -> list[dict]:
    """The page's record once its newest message is `t_s` of the log or later."""
    wait_for_log_time(page, t_s)
    return page.evaluate("window.__osd")


def during(record: list[dict], span: tuple[float, float]) -> list[dict]:
    """What the OSD showed while the newest message was within `span` (a fade: the last
    message before it)."""
    return [r for r in record if span[0] - 0.1 <= r["t"] < span[1]]


def wait_for_log_time(page, t_s: float) -> None:
    page.wait_for_function(
        "([t0, t]) => window.fpvDebug.feed.latest && window.fpvDebug.feed.latest.t_server_mono - t0 >= t",
        arg=[T0, t_s],
        timeout=60_000,
    )


def timer_s(text: str) -> int:
    mm, ss = text.split(":")
    return 60 * int(mm) + int(ss)


@pytest.mark.timeout(180)
def test_a_quarter_speed_replay_keeps_fresh_what_is_fresh_in_the_log(browser, tmp_path):
    """Fades of 0.8 s in the log (3.2 s of wall time at x0.25), between heartbeats: nothing
    goes stale in the log (the heartbeat is at most 1 s old, ATTITUDE 0.8 s, no 2 s
    without a message), so nothing may on the OSD; and the flight timer counts the log's
    seconds, not the wall's four times as many."""
    fades = [(3.1, 3.9), (5.1, 5.9)]
    path = armed_log(tmp_path / "fades.tlog", 6.5, fades)
    with replay_station(path, "0.25", tmp_path) as base:
        page, start = open_osd(browser, base, ready_before_s=fades[0][0] - 0.5)
        record = record_until(page, 6.2)
    assert len(record) > 20, record
    seen = [r for r in record if r["t"] >= start]
    stale = [r for r in seen if "osd-stale" in r["mode"] or "osd-stale" in r["altitude"]]
    assert stale == [], stale[:3]
    lost = [r for r in seen if "LINK LOST" in r["warning"]]
    assert lost == [], lost[:3]
    # The timer shows whole seconds armed: the log's time since its first heartbeat (0 s),
    # give or take the second of a heartbeat's interval, however long a fade is on the wall.
    off = [r for r in seen if not -1.5 <= timer_s(r["timer"]) - r["t"] <= 1.0]
    assert off == [], off[:3]


@pytest.mark.timeout(180)
def test_a_4x_replay_greys_what_is_stale_in_the_log_and_holds_at_its_end(browser, tmp_path):
    """A 4 s fade in the log (1 s of wall time at x4): the altitude's group is stale after
    2 s of it in the log, and no message for 2 s is LINK LOST, so the OSD greys it and
    warns. When the log ends its clock stops: the OSD's ages and the flight timer hold."""
    fade = (40.05, 44.05)
    end_s = 52.0  # 2 s of wall time after the fade: for a loaded machine to draw it fresh
    path = armed_log(tmp_path / "fade.tlog", end_s, [fade])
    # The station's own link-lost (no heartbeat for link_lost_s) would send a message
    # during the fade; the OSD's ages are what is tested, not the station's.
    with replay_station(path, "4", tmp_path, **{"link.link_lost_s": 10.0}) as base:
        page, _ = open_osd(browser, base, ready_before_s=fade[0] - 4)
        in_fade = during(record_until(page, fade[1] + 1.0), fade)
        assert any("osd-stale" in r["altitude"] for r in in_fade), in_fade[-5:]
        assert any("LINK LOST" in r["warning"] for r in in_fade), in_fade[-5:]
        # After the fade, fresh again: a change the page recorded, waited for (a starved
        # page may draw it late; the replay's end greys everything again, so the live
        # class is no witness once the page knows the log has ended).
        page.wait_for_function(
            "(t) => window.__osd.some((r) => r.t >= t && !r.altitude.includes('osd-stale'))",
            arg=fade[1],
            timeout=60_000,
        )

        # The end of the log: its time stands still, and so do the ages and the timer.
        get = lambda url: httpx.get(f"{base}{url}", timeout=30).json()  # noqa: E731
        assert wait_until(lambda: get("/api/status")["link"]["replay_done"], timeout=60)
        page.wait_for_function("window.fpvDebug.feed.ended", timeout=15_000)
        age, timer = (page.locator(f"[data-osd={n}]") for n in ("age", "timer"))
        held = age.text_content(), timer.text_content()
        page.wait_for_timeout(1500)
        assert (age.text_content(), timer.text_content()) == held
        assert abs(timer_s(held[1]) - end_s) <= 1.5, held
        assert re.fullmatch(r"TLM 0\.\ds VID .*", held[0]), held
        expect(page.locator("#link-banner-detail")).to_have_text("the replay has ended")


@pytest.mark.timeout(180)
def test_the_banner_and_the_osd_say_link_lost_after_the_same_silence(browser, tmp_path):
    """A 2.5 s fade in the log (5 s of wall time at x0.5): no message for 2 s is LINK LOST
    on the OSD, and the page's banner says "telemetry stopped" after the same 2 s (it
    waited 3 s, so a fade between 2 and 3 s showed LINK LOST on the OSD only)."""
    fade = (4.05, 6.55)
    path = armed_log(tmp_path / "fade.tlog", 9.0, [fade])
    # No station link-lost message during the fade: the page's own clock is tested.
    with replay_station(path, "0.5", tmp_path, **{"link.link_lost_s": 10.0}) as base:
        page, _ = open_osd(browser, base, ready_before_s=fade[0] - 1)
        record = record_until(page, fade[1] + 0.5)
    in_fade = during(record, fade)
    assert any("LINK LOST" in r["warning"] for r in in_fade), in_fade[-5:]
    shown = [r for r in in_fade if r["banner"]]
    assert shown and shown[0]["detail"] == "telemetry stopped", in_fade[-5:]
    # After the fade, the banner goes again.
    assert not record[-1]["banner"], record[-3:]
