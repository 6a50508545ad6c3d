"""The OSD's cost per frame in headless Chromium (target: under 2 ms).

    python benchmarks/osd_frame_cost.py [--seconds 10] [--size 1280x720 1920x1080]

Starts a real station (uvicorn in this process) following the test MAVLink vehicle over
UDP (attitude at 50 Hz, the rest at its default rates, the vehicle rolling and yawing all
the time so that the horizon and the tape redraw on every new message), opens
/goggles.html in headless Debian chromium at each size, and after a warm-up reads
window.fpvDebug.osd.stats: osd.js times each animation frame's OSD work with
performance.now() (the Performance API's clock). Two figures per size:

  draw     the script's work: what it sets and the canvas commands it records;
  +raster  the same with the canvases rasterized inside the timing (stats.raster:
           one pixel read back from each), which a software canvas (--disable-gpu, and a
           Pi without GPU canvas) otherwise pays later in the frame, out of sight.

Printed per size and mode: frames, per-frame p50/p99/max ms. Note the load average.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


from fpv_station.server.app import create_app  # noqa: E402
from tests.helpers import chromium, run_uvicorn, station_settings  # noqa: E402
from tests.mav_vehicle import DEFAULT_RATES_HZ, MavVehicle  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--size", nargs="+", default=["1280x720", "1920x1080"])
    args = ap.parse_args()
    print(
        f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}"
    )
    rates = dict(DEFAULT_RATES_HZ, ATTITUDE=50.0)
    with tempfile.TemporaryDirectory() as tmp, MavVehicle("udp", rates_hz=rates) as vehicle:
        stop = threading.Event()

        def wobble() -> None:  # roll, pitch and yaw always changing: every message redraws
            t0 = time.monotonic()
            while not stop.is_set():
                t = time.monotonic() - t0
                vehicle.roll_rad = math.radians(25 * math.sin(t))
                vehicle.pitch_rad = math.radians(10 * math.sin(0.7 * t))
                vehicle.yaw_rad = math.radians((40 * t) % 360)
                time.sleep(0.01)

        threading.Thread(target=wobble, daemon=True).start()
        settings = station_settings(vehicle.station_source, Path(tmp) / "sessions")
        with run_uvicorn(create_app(settings)) as base, chromium() as browser:
            for size in args.size:
                w, h = (int(v) for v in size.split("x"))
                page = browser.new_page(viewport={"width": w, "height": h})
                page.goto(base + "/goggles.html")
                page.wait_for_function(
                    "document.querySelector('[data-osd=mode]').textContent !== ''", timeout=15000
                )
                page.wait_for_timeout(2000)  # warm-up: JIT, first layout
                for mode, raster in (("draw", False), ("+raster", True)):
                    page.evaluate(
                        "(raster) => { const s = fpvDebug.osd.stats; s.recent.length = 0; s.frames = 0;"
                        " s.totalMs = 0; s.keep = 1e6; s.raster = raster; }",
                        raster,
                    )
                    page.wait_for_timeout(args.seconds * 1000)
                    ms = sorted(page.evaluate("fpvDebug.osd.stats.recent.slice()"))
                    frames = page.evaluate("fpvDebug.osd.stats.frames")
                    p50 = statistics.median(ms)
                    p99 = ms[min(len(ms) - 1, int(0.99 * len(ms)))]
                    print(
                        f"{size} {mode}: {frames} frames in {args.seconds:.0f} s "
                        f"({frames / args.seconds:.0f}/s), OSD per frame p50 {p50:.3f} ms, "
                        f"p99 {p99:.3f} ms, max {ms[-1]:.3f} ms, mean {statistics.fmean(ms):.3f} ms"
                    )
                page.close()
        stop.set()
    print(
        f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}"
    )


if __name__ == "__main__":
    main()
