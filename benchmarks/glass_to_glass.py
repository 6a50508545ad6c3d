"""Render-to-screen latency of the twin's front camera in headless Chromium, 1 and 6 tabs.

    python benchmarks/glass_to_glass.py [--seconds 20] [--tabs 1 6] [--fps 30] [--size 640x480]

Starts a real twin station (uvicorn in this process), opens N pilot pages in one browser
context and, after a warm-up, collects for `--seconds` every front-camera frame each page
draws (web/video.js `cameras.log`, window.fpvDebug.cameras.log). The twin stamps each frame's render time into its
corner (companion/cameras/frame_stamp.py); the page reads it from the decoded picture in
the animation frame that draws it. Printed per tab count:

  render->screen   p50 / p99 ms: stamp to the animation frame that draws the picture
                   (the display shows it at its next refresh, up to one more refresh);
  station share    p50 / p99 ms: stamp until the page received the message (render,
                   JPEG encode, fan-out, the socket); the rest is the browser's decode
                   and wait for its next animation frame;
  frames drawn per second per page, and the frames whose code did not read.

Note the load average printed first: the figures are the whole machine's, Chromium's
pages and the station share its cores.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fpv_station.server.app import create_app  # noqa: E402
from tests.helpers import chromium, run_uvicorn, wait_until  # noqa: E402
from tests.twin_flights import twin_station_settings  # noqa: E402


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] if ordered else float("nan")


def measure(base: str, browser, tabs: int, seconds: float) -> dict:
    context = browser.new_context(viewport={"width": 1280, "height": 720})
    pages = []
    for _ in range(tabs):
        page = context.new_page()
        page.goto(base + "/", timeout=120_000)
        pages.append(page)
    for page in pages:
        page.wait_for_function(
            "() => window.fpvDebug && window.fpvDebug.cameras.frames.front", timeout=120_000
        )
    pages[0].wait_for_timeout(3000)  # warm-up: JIT, first layout, the twin's textures
    for page in pages:
        page.evaluate("() => { window.fpvDebug.cameras.log = []; }")
    pages[0].wait_for_timeout(seconds * 1000)
    rows = []
    for page in pages:
        rows += page.evaluate(
            "() => { const l = window.fpvDebug.cameras.log; window.fpvDebug.cameras.log = null; return l; }"
        )
    context.close()
    front = [r for r in rows if r["camera"] == "front"]
    stamped = [r for r in front if r["kind"] == "render"]
    return {
        "tabs": tabs,
        "frames": len(front),
        "unread": len(front) - len(stamped),
        "fps_per_page": len(front) / tabs / seconds,
        "p50": pct([r["totalMs"] for r in stamped], 0.5),
        "p99": pct([r["totalMs"] for r in stamped], 0.99),
        "station_p50": pct([r["stationMs"] for r in stamped], 0.5),
        "station_p99": pct([r["stationMs"] for r in stamped], 0.99),
        "station_share": statistics.median(
            [r["stationMs"] / r["totalMs"] for r in stamped if r["totalMs"] > 0] or [float("nan")]
        ),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--tabs", type=int, nargs="+", default=[1, 6])
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--size", default="640x480", help="the cameras' frame size")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    load = os.getloadavg()
    print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}, {os.cpu_count()} cores")
    overrides: dict = {"recording.auto_record_on_arm": False}
    for name in ("front", "bottom"):
        overrides |= {
            f"cameras.{name}.width": w,
            f"cameras.{name}.height": h,
            f"cameras.{name}.fps": args.fps,
        }
    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(twin_station_settings(Path(tmp), overrides))
        with run_uvicorn(app) as base, chromium() as browser:
            wait_until(lambda: app.state.station.cameras["front"].frames.get(), timeout=60)
            print(
                f"twin front+bottom cameras {w}x{h} at {args.fps:g} fps; "
                f"{args.seconds:g} s per run; ms from the render stamp"
            )
            print(
                f"{'tabs':>4} {'frames':>7} {'fps/page':>8} {'unread':>6} "
                f"{'p50':>7} {'p99':>7} {'station p50':>11} {'station p99':>11} {'share':>6}"
            )
            for tabs in args.tabs:
                r = measure(base, browser, tabs, args.seconds)
                print(
                    f"{r['tabs']:>4} {r['frames']:>7} {r['fps_per_page']:>8.1f} "
                    f"{r['unread']:>6} {r['p50']:>7.1f} {r['p99']:>7.1f} "
                    f"{r['station_p50']:>11.1f} {r['station_p99']:>11.1f} "
                    f"{r['station_share']:>6.0%}"
                )
    load = os.getloadavg()
    print(f"load average after {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")


if __name__ == "__main__":
    main()
