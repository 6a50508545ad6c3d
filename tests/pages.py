"""Pages in headless Chromium (the `browser` fixture, tests/helpers.chromium): a page that
may reach only the station, as on the field's closed network, and boxes on a page."""

from __future__ import annotations

import re

# Every tab live (tests/test_video_tabs.py, benchmarks/glass_to_glass.py): three pilot
# pages, two goggles and the sessions page, in one browser.
SIX_TABS = ["/", "/", "/", "/goggles.html", "/goggles.html", "/sessions.html"]


# Any address but the station's (and the page's own data: and blob: URLs).
NOT_LOCAL = re.compile(r"^(?!http://127\.0\.0\.1|ws://127\.0\.0\.1|data:|blob:)")


def open_offline(browser, outside: list[str]):
    """A page that may only reach the station (the Pi has no internet)."""
    page = browser.new_page(viewport={"width": 960, "height": 640})  # software WebGL: keep it small
    # The viser iframe renders WebGL in software on the page's renderer: on a starved CI box
    # a plain evaluate waited more than Playwright's 30 s default for the main thread. A
    # hang guard, not a speed figure (benchmarks/trajectory3d.py has those).
    page.set_default_timeout(90_000)

    def turned_away(route):
        outside.append(route.request.url)
        route.abort()

    # Only what is not the station's is routed: Playwright runs a route's handler only
    # while the test's thread is in one of its calls, so a station request routed too
    # would wait out any plain `time.sleep` of the test.
    page.route(NOT_LOCAL, turned_away)
    return page


def overlap(a: dict, b: dict) -> bool:
    """Whether two bounding boxes (Playwright's x, y, width, height) overlap."""
    return (
        a["x"] < b["x"] + b["width"]
        and b["x"] < a["x"] + a["width"]
        and a["y"] < b["y"] + b["height"]
        and b["y"] < a["y"] + a["height"]
    )
