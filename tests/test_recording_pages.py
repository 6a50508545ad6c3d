"""The sessions page and the pilot page's REC button in real headless chromium."""

import httpx
import pytest
from playwright.sync_api import expect

from tests.stations import no_link_station


@pytest.fixture
def base(tmp_path):
    with no_link_station(tmp_path / "sessions") as (url, _):
        yield url


@pytest.fixture
def page(browser):
    pg = browser.new_page()
    pg.on("dialog", lambda d: d.accept())
    yield pg
    pg.context.close()


def test_sessions_page_lists_downloads_and_deletes(base, page):
    sid = httpx.post(f"{base}/api/recording/start").json()["id"]
    httpx.post(f"{base}/api/recording/stop")
    page.goto(f"{base}/sessions.html")
    row = page.locator(f'#sessions tr[data-id="{sid}"]')
    expect(row).to_have_count(1)
    expect(row).to_contain_text("complete")
    expect(row).to_contain_text("rows")
    href = row.locator("a.download").get_attribute("href")
    assert httpx.get(base + href).content[:2] == b"PK"
    row.locator("button.delete").click()
    expect(row).to_have_count(0)
    expect(page.locator("#empty")).to_be_visible()
    assert httpx.get(f"{base}/api/sessions").json() == []


def test_rec_button_starts_shows_elapsed_and_stops(base, page):
    page.goto(f"{base}/")
    button = page.locator("#toolbar #rec-button")
    expect(button).to_have_text("REC")
    button.click()
    expect(button).to_have_class("recording")
    expect(button).to_contain_text("STOP 00:0")
    assert httpx.get(f"{base}/api/recording").json()["recording"] is True
    page.wait_for_timeout(1300)
    expect(button).not_to_contain_text("STOP 00:00")  # the elapsed time ticks
    button.click()
    expect(button).to_have_text("REC")
    status = httpx.get(f"{base}/api/recording").json()
    assert status["recording"] is False and status["last_stop"]["reason"] == "requested"
