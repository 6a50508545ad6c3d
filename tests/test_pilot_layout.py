"""The pilot page's layout in real headless chromium, at a desktop and a phone's two
orientations, against a real station following the test MAVLink vehicle: on a laptop
the front camera's picture is at least 0.6 of the width (the paper's large front view),
and, with a flight task shown, the 3D panel open never covers the flight state, nor
anything else does."""

from __future__ import annotations

import httpx
import pytest
from playwright.sync_api import expect

from tests.helpers import PICTURE_WIDTH
from tests.pages import overlap
from tests.stations import vehicle_station


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    panel = {"viser.enabled": True, "viser.port": 0}
    with vehicle_station(tmp_path_factory.mktemp("sessions"), **panel) as station:
        # A flight task shown: on a laptop the flight state is then a strip under the
        # front camera, its long values (the altitude's reference) cut to fit it.
        tasks = httpx.get(f"{station[1]}/api/task").json()["tasks"]
        reply = httpx.post(f"{station[1]}/api/task", json={"task_id": tasks[-1]["id"]})
        assert reply.status_code == 200, reply.text
        yield station


# Is the element at the centre of each flight-state value the value itself (not the 3D
# panel, nor anything else drawn over it)? Scrolled into view first: reachable counts.
VALUES_ON_TOP = """() => [...document.querySelectorAll('#flight-state td')].map((td) => {
  td.scrollIntoView({ block: 'center', inline: 'center' });
  const r = td.getBoundingClientRect();
  const hit = document.elementFromPoint(r.x + r.width / 2, r.y + r.height / 2);
  return [td.closest('tr').querySelector('th').textContent.trim(), td.contains(hit)];
})"""


@pytest.mark.parametrize("size", [(1280, 720), (390, 844), (844, 390)])
def test_3d_panel_open_leaves_the_flight_state_in_view(station, browser, size):
    vehicle, base = station
    context = browser.new_context(viewport={"width": size[0], "height": size[1]})
    page = context.new_page()
    # The viewer inside the panel renders in software here and is not what is tested: the
    # panel's place is. Its requests to the viser server are turned away.
    page.route("**/*", lambda r: r.continue_() if r.request.frame == page.main_frame else r.abort())
    page.goto(base + "/")
    expect(page.locator("#v-mode")).to_have_text("POSCTL", timeout=30_000)
    expect(page.locator("#v-rel-alt-ref")).to_contain_text("GPS fix")
    if size == (1280, 720):
        picture, width = page.evaluate(PICTURE_WIDTH, "front-view")
        assert picture >= 0.6 * width, (picture, width)
    page.locator("#p3d-toggle").click()
    panel = page.locator("#panel-3d")
    expect(panel).to_be_visible()
    for enlarged in (False, True):
        if enlarged:
            page.locator("#p3d-enlarge").click()
            expect(panel).to_have_class("p3d-large")
        sw, cw = page.evaluate(
            "[document.documentElement.scrollWidth, document.documentElement.clientWidth]"
        )
        assert sw <= cw, (size, sw, cw)  # and no sideways scrolling
        covered = [name for name, on_top in page.evaluate(VALUES_ON_TOP) if not on_top]
        assert covered == [], (size, enlarged, covered)
        panel_box = panel.bounding_box()
        assert panel_box["width"] > 200 and panel_box["height"] > 150, panel_box
        for td in page.locator("#flight-state td").all():
            assert not overlap(td.bounding_box(), panel_box), (size, enlarged, td.inner_text())
        # The front camera keeps a view of its own too.
        front = page.locator("#front-view").bounding_box()
        assert front["height"] > 100 and not overlap(front, panel_box), (size, front, panel_box)
    context.close()
