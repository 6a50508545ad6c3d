"""What every page shares (web/lib.js, web/style.css), in real headless chromium against a
real station: the one 401 -> ask -> retry flow for HTTP and for the control WebSocket, and
pages that style only through the one stylesheet and load only the station's own scripts."""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import expect

from fpv_station.companion.vehicle_state import VehicleState
from fpv_station.server.app import create_app
from tests.helpers import run_uvicorn, station_settings
from tests.stations import no_link_station
from tests.synthetic import SESSION_A

TOKEN = "s3cret-token"
# Each page, and what shows once all its scripts have run.
PAGES = {
    "/": "#p3d-toggle",
    "/sessions.html": f'#sessions tr[data-id="{SESSION_A}"] a.replay',
    "/analysis.html": f'#sessions option[value="{SESSION_A}"]',
    f"/replay.html?session={SESSION_A}": "#replay-status:has-text('fixes')",
    "/goggles.html": ".osd-menu-button",
}
WEB_DIR = Path(__file__).resolve().parents[1] / "web"


@pytest.fixture
def guarded(tmp_path):
    """A station with a control token; yields its base URL."""
    with no_link_station(tmp_path / "sessions", **{"server.token": TOKEN}) as (base, _):
        yield base


def answer_dialogs(page, token: str | None) -> list[str]:
    """Accept confirms; answer prompts with `token` (None = cancel). Returns the prompts."""
    prompts: list[str] = []

    def on_dialog(dialog):
        if dialog.type == "prompt":
            prompts.append(dialog.message)
            if token is None:
                dialog.dismiss()
            else:
                dialog.accept(token)
        else:
            dialog.accept()

    page.on("dialog", on_dialog)
    return prompts


def test_http_401_asks_for_the_token_once_retries_and_keeps_it(guarded, browser):
    auth = {"Authorization": f"Bearer {TOKEN}"}
    sid = httpx.post(f"{guarded}/api/recording/start", headers=auth).json()["id"]
    httpx.post(f"{guarded}/api/recording/stop", headers=auth).raise_for_status()

    page = browser.new_page()
    prompts = answer_dialogs(page, TOKEN)
    deletes: list[str | None] = []
    page.on(
        "request",
        lambda r: deletes.append(r.headers.get("authorization")) if r.method == "DELETE" else None,
    )
    page.goto(f"{guarded}/sessions.html")
    row = page.locator(f'#sessions tr[data-id="{sid}"]')
    row.locator("button.delete").click()
    expect(row).to_have_count(0)
    assert httpx.get(f"{guarded}/api/sessions").json() == []
    assert len(prompts) == 1 and "token" in prompts[0]
    assert deletes == [None, f"Bearer {TOKEN}"]  # refused, asked, retried with the token
    assert page.evaluate("localStorage.getItem('fpv.token')") == TOKEN

    # Another page of the same station uses the kept token without asking again.
    page.goto(f"{guarded}/")
    button = page.locator("#rec-button")
    button.click()
    expect(button).to_have_class("recording")
    button.click()
    expect(button).to_have_text("REC")
    assert len(prompts) == 1


def test_the_printed_url_token_is_kept_and_leaves_the_address_bar(guarded, browser):
    """`fpv-station serve` prints http://HOST:PORT/?token=...: the page keeps the token,
    drops it from the URL, and controls the station without asking."""
    page = browser.new_page()
    prompts = answer_dialogs(page, None)
    page.goto(f"{guarded}/?token={TOKEN}#x")
    assert page.evaluate("localStorage.getItem('fpv.token')") == TOKEN
    assert page.url == f"{guarded}/#x"
    button = page.locator("#rec-button")
    button.click()
    expect(button).to_have_class("recording")
    assert httpx.get(f"{guarded}/api/recording").json()["recording"] is True
    assert prompts == []


def test_http_401_declined_shows_the_servers_error_and_changes_nothing(guarded, browser):
    page = browser.new_page()
    alerts: list[str] = []
    page.on("dialog", lambda d: (alerts.append(d.message), d.dismiss()))
    page.goto(f"{guarded}/")
    page.locator("#rec-button").click()
    expect(page.locator("#rec-button")).to_have_text("REC")
    page.wait_for_function("document.getElementById('rec-button').disabled === false")
    # the prompt (declined), then the refusal in the server's words, as a toast
    assert "token" in alerts[0]
    toast = page.locator("#toast")
    expect(toast).to_be_visible()
    expect(toast).to_contain_text("Recording: This station requires a control token")
    assert len(alerts) == 1
    assert httpx.get(f"{guarded}/api/recording").json()["recording"] is False


def test_control_socket_4401_asks_for_the_token_and_reconnects(guarded, browser):
    """The control socket refuses a missing token (close 4401); the page asks through
    lib.js and opens it again with the token. This station has no vehicle link, so the
    socket then gets past the token and is refused for that reason instead."""
    page = browser.new_page()
    prompts = answer_dialogs(page, TOKEN)
    page.goto(f"{guarded}/")
    page.wait_for_function("window.fpvDebug && window.fpvDebug.control")
    page.evaluate("document.getElementById('ctl-toggle').click()")  # hidden without a twin
    page.wait_for_function(
        "window.fpvDebug.control.lastReply && window.fpvDebug.control.lastReply.error === 'Conflict'"
    )
    assert len(prompts) == 1
    assert "No vehicle to command" in page.evaluate("window.fpvDebug.control.lastReply.error_msg")


def test_a_declined_token_is_not_asked_for_again_by_a_waiting_command(guarded, browser):
    """Arm with the sticks off opens the control socket and retries the command while it
    opens; the station refuses it (4401) and the pilot declines the token prompt: the
    command is dropped, not retried into a prompt after every refusal."""
    page = browser.new_page()
    prompts = answer_dialogs(page, None)
    page.goto(f"{guarded}/")
    page.wait_for_function("window.fpvDebug && window.fpvDebug.control")
    # (the sticks are off from the start: the first prompt is what says the socket was
    # refused and declined)
    with page.expect_event("dialog", timeout=30_000):
        page.evaluate("document.getElementById('ctl-arm').click()")  # hidden without a twin
    page.wait_for_timeout(4000)  # longer than the command's retries left (10 x 300 ms)
    assert len(prompts) == 1, prompts


# Records <style> elements as they are added, from before the page's first script runs.
WATCH_STYLES = """
window.__styles = [];
new MutationObserver((muts) => {
  for (const m of muts) for (const n of m.addedNodes)
    if (n.nodeName === "STYLE") window.__styles.push(n.textContent.slice(0, 80));
}).observe(document, { childList: true, subtree: true });
"""


@pytest.mark.timeout(180)
def test_pages_style_only_through_the_stylesheet_and_load_only_own_scripts(
    two_sessions_dir,
    browser,
):
    settings = station_settings(
        "none", two_sessions_dir, **{"viser.enabled": True, "viser.port": 0}
    )
    with run_uvicorn(create_app(settings)) as base:
        page = browser.new_page()
        page.add_init_script(WATCH_STYLES)
        scripts: list[str] = []
        page.on(
            "request",
            lambda r: (
                scripts.append(r.url)
                if r.resource_type == "script" and r.frame == page.main_frame
                else None
            ),
        )
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        for path, ready in PAGES.items():
            scripts.clear()
            page.goto(base + path)
            expect(page.locator(ready)).to_have_count(1, timeout=20_000)
            found = page.evaluate(
                """() => ({
                  injected: window.__styles,
                  styles: document.querySelectorAll("style").length,
                  styled: [...document.querySelectorAll("[style]")].map((e) => e.outerHTML.slice(0, 80)),
                  sheets: [...document.querySelectorAll("link[rel=stylesheet]")].map((l) => l.href),
                  classic: [...document.querySelectorAll("script")].filter((s) => s.type !== "module").length,
                })"""
            )
            assert found["injected"] == [] and found["styles"] == 0, (path, found)
            assert found["styled"] == [], (path, found["styled"])
            assert found["sheets"] == [f"{base}/style.css"], (path, found["sheets"])
            assert found["classic"] == 0, path  # every page script is an ES module
            assert scripts and all(u.startswith(base + "/") for u in scripts), (path, scripts)
            assert f"{base}/lib.js" in scripts, (path, scripts)
        assert errors == []


def test_live_socket_sends_acks_and_closes_for_good(tmp_path, browser):
    """lib.js's liveSocket on `/ws/telemetry?ack=1`: the station sends the next state only
    after the page's ack, so more than one message arriving proves `send` reached it;
    after `close()` nothing more arrives (no reconnect)."""
    app = create_app(station_settings("none", tmp_path / "sessions"))
    with run_uvicorn(app) as base:
        page = browser.new_page()
        page.goto(f"{base}/sessions.html")
        page.evaluate(
            """async () => {
              const { liveSocket } = await import("/lib.js");
              window.__got = [];
              const s = liveSocket("/ws/telemetry?ack=1", { message(m) {
                window.__got.push(m.version);
                s.send({ ack: m.version });
              } });
              window.__sock = s;
            }"""
        )
        slot = app.state.station.state

        def publish_until(n: int) -> bool:
            for _ in range(100):
                slot.publish(VehicleState())
                time.sleep(0.05)
                if page.evaluate("window.__got.length") >= n:
                    return True
            return False

        assert publish_until(4), page.evaluate("window.__got")
        got = page.evaluate("window.__got")
        assert got == sorted(set(got))  # each state once, in order
        page.evaluate("window.__sock.close()")
        page.wait_for_timeout(300)
        before = page.evaluate("window.__got.length")
        for _ in range(10):
            slot.publish(VehicleState())
            time.sleep(0.05)
        page.wait_for_timeout(1500)  # longer than the first reconnect delay
        assert page.evaluate("window.__got.length") == before


def test_every_page_links_to_the_analysis_page(two_sessions_dir, browser):
    pages = {path.split("?")[0].lstrip("/") or "index.html" for path in PAGES}
    assert pages == {p.name for p in WEB_DIR.glob("*.html")}  # a new page is tested too
    settings = station_settings("none", two_sessions_dir)
    with run_uvicorn(create_app(settings)) as base:
        page = browser.new_page(viewport={"width": 1280, "height": 720})
        for path in PAGES:
            page.goto(base + path)
            if path == "/goggles.html":  # no chrome: the links are in the OSD menu (O)
                page.locator(".osd-menu-button").wait_for(state="attached")
                page.keyboard.press("o")
            link = page.locator('a[href="/analysis.html"]').first
            expect(link).to_be_visible()
            if path != "/analysis.html":
                link.click()
                expect(page).to_have_url(base + "/analysis.html")
