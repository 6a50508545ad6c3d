"""Both cameras keep their aspect ratio and a usable size on the pilot and goggles pages,
for 4:3 and 16:9 cameras, at a laptop's 1280x800 and goggles' 1920x1080 (stereo too), in
real headless chromium against a real station whose cameras are folders of frames of that
size. What is measured is the picture as drawn: the video canvas's box, its object-fit and
the frames' size, clipped by its view and the window."""

from __future__ import annotations

import pytest
from playwright.sync_api import expect

from fpv_station.server.app import create_app
from tests.helpers import run_uvicorn, station_settings
from tests.video_fixtures import write_images

SIZES = {"4:3": (640, 480), "16:9": (1280, 720)}


# One station per pair of camera shapes: each shape is seen by each camera in one of them.
@pytest.fixture(
    scope="module", params=[("16:9", "4:3"), ("4:3", "16:9")], ids=lambda p: "-".join(p)
)
def station(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cams")
    specs = {}
    for camera, shape in zip(("front", "bottom"), request.param, strict=True):
        w, h = SIZES[shape]
        folder = write_images(tmp / camera, 2, (w, h))
        specs[f"cameras.{camera}.spec"] = f"folder:{folder}?width={w}&height={h}"
    settings = station_settings("none", tmp / "sessions", **specs)
    with run_uvicorn(create_app(settings)) as base:
        yield base, dict(zip(("front", "bottom"), request.param, strict=True))


# Each shown camera picture: its frames' size, the canvas's box, the picture drawn in it
# (object-fit and object-position's default centre) and what of it is visible: inside its
# view and the window, at the page's first scroll position.
PICTURES = """() => [...document.querySelectorAll('.video-stream')]
  .filter((img) => img.offsetParent !== null).map((img) => {
  const nw = img.width, nh = img.height;  // a canvas, its frames' size
  const box = img.getBoundingClientRect(), view = img.closest('.view').getBoundingClientRect();
  const fit = getComputedStyle(img).objectFit;
  let sx = box.width / nw, sy = box.height / nh;
  if (fit === 'contain') sx = sy = Math.min(sx, sy);
  else if (fit === 'cover') sx = sy = Math.max(sx, sy);
  const pw = nw * sx, ph = nh * sy;
  const left = box.left + (box.width - pw) / 2, top = box.top + (box.height - ph) / 2;
  const vw = Math.min(left + pw, view.right, innerWidth) - Math.max(left, view.left, 0);
  const vh = Math.min(top + ph, view.bottom, innerHeight) - Math.max(top, view.top, 0);
  return {view: img.closest('.view').id, nw, nh, sx, sy, pw, ph, fit, bottom: view.bottom,
          boxW: box.width, boxH: box.height,
          visible: Math.max(0, vw) * Math.max(0, vh) / (pw * ph), shownW: Math.max(0, vw)};
})"""


def pictures(page) -> dict:
    page.wait_for_function(
        """() => [...document.querySelectorAll('.video-stream')]
          .filter((img) => img.offsetParent !== null).every((img) => img.dataset.frames > 0)""",
        timeout=30_000,
    )
    return {p["view"]: p for p in page.evaluate(PICTURES)}


def check_aspect(p: dict, shape: str) -> None:
    w, h = SIZES[shape]
    assert (p["nw"], p["nh"]) == (w, h), p
    assert abs(p["sx"] - p["sy"]) <= 0.01 * p["sx"], p  # not stretched


def box_is_the_picture(p: dict) -> None:
    """The view's camera element itself has the picture's shape (no bars inside it, and
    an OSD over it lies over the picture)."""
    ratio = p["nw"] / p["nh"]
    assert abs(p["boxW"] / p["boxH"] - ratio) <= 0.02 * ratio, p


@pytest.mark.parametrize("size", [(1280, 720), (1280, 800), (1920, 1080)])
def test_pilot_page_cameras_keep_their_shape_and_size_with_a_task_shown(station, browser, size):
    """With a task selected (its panel above the bottom camera, the flight state a strip
    under the front camera) the bottom camera keeps its own aspect ratio at the column's
    width or the height the task leaves it, at least 0.3 of the screen's width and
    height, on the screen. At 720 px the front camera gives up the height of the flight
    state; the task panel is seen whole (tests/test_task_fit.py)."""
    base, shapes = station
    w, h = size
    page = browser.new_page(viewport={"width": w, "height": h})
    tasks = page.request.get(base + "/api/task").json()["tasks"]
    assert tasks, "the station's scene has no task to show"
    reply = page.request.post(base + "/api/task", data={"task_id": tasks[-1]["id"]})
    assert reply.ok, reply.text()
    page.goto(base + "/")
    expect(page.locator("#task-steps li").first).to_be_attached(timeout=15_000)
    pics = pictures(page)
    assert set(pics) == {"front-view", "bottom-view"}, pics
    for name in ("front", "bottom"):
        p = pics[f"{name}-view"]
        check_aspect(p, shapes[name])
        assert p["visible"] >= 0.99, p  # the whole picture, on the screen without scrolling
    assert pics["front-view"]["shownW"] >= (0.55 if h <= 720 else 0.6) * w, pics["front-view"]
    bottom = pics["bottom-view"]
    box_is_the_picture(bottom)
    assert bottom["shownW"] >= 0.3 * w and bottom["ph"] >= 0.3 * h, bottom
    # The flight state, a strip under the front camera, is seen too.
    state = page.locator("#flight-state").bounding_box()
    assert state["y"] + state["height"] <= h and state["y"] >= pics["front-view"]["bottom"], state
    # The step the pilot is on is in view.
    inside = page.evaluate(
        """() => { const li = document.querySelector('#task-steps li.current');
        const r = li.getBoundingClientRect();
        const p = document.querySelector('#task-panel').getBoundingClientRect();
        return r.top >= p.top && r.bottom <= p.bottom && r.bottom <= innerHeight; }"""
    )
    assert inside
    page.close()


def test_goggles_cameras_keep_their_shape_full_screen_pip_and_stereo(station, browser):
    base, shapes = station
    w, h = 1920, 1080
    page = browser.new_page(viewport={"width": w, "height": h})
    page.goto(base + "/goggles.html")
    front = pictures(page)["front-view"]
    check_aspect(front, shapes["front"])
    # Full screen: the picture covers the screen (a 4:3 one loses its top and bottom).
    assert front["fit"] == "cover" and front["boxW"] >= w - 1 and front["boxH"] >= h - 1, front
    assert front["visible"] >= 0.74, front

    page.keyboard.press("b")  # the bottom camera, picture-in-picture
    expect(page.locator("#bottom-view")).to_be_visible()
    bottom = pictures(page)["bottom-view"]
    check_aspect(bottom, shapes["bottom"])
    box_is_the_picture(bottom)
    assert bottom["visible"] >= 0.99 and bottom["shownW"] >= 0.25 * w, bottom
    page.keyboard.press("b")

    page.keyboard.press("s")  # side-by-side stereo: each eye the whole picture
    expect(page.locator("#front-view-right")).to_be_visible()
    eyes = pictures(page)
    for view in ("front-view", "front-view-right"):
        p = eyes[view]
        check_aspect(p, shapes["front"])
        box_is_the_picture(p)
        assert p["visible"] >= 0.99 and p["shownW"] >= 0.49 * w, p
    page.close()
