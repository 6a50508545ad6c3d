"""Every page names its icon, and the icon is an image the browser draws (real headless
chromium against a real station)."""

from __future__ import annotations

import pytest

from tests.stations import no_link_station

PAGES = ("/", "/goggles.html", "/sessions.html", "/analysis.html", "/replay.html")


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    with no_link_station(tmp_path_factory.mktemp("sessions")) as (url, _):
        yield url


@pytest.mark.parametrize("path", PAGES)
def test_every_page_has_a_favicon(base, browser, path):
    page = browser.new_page()
    page.goto(base + path, wait_until="domcontentloaded")
    href = page.locator("link[rel=icon]").get_attribute("href")
    assert href, f"{path} names no icon"
    reply = page.request.get(base + href)
    assert reply.ok and reply.headers["content-type"].startswith("image/svg+xml"), reply
    size = page.evaluate(
        """(href) => new Promise((done) => { const img = new Image();
        img.onload = () => done([img.naturalWidth, img.naturalHeight]);
        img.onerror = () => done(null); img.src = href; })""",
        href,
    )
    assert size and size[0] > 0 and size[1] > 0, size
