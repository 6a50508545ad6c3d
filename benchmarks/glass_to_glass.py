"""Render-to-screen latency of the twin's front camera in headless Chromium, 1 and 6 pages.

    python benchmarks/glass_to_glass.py [--seconds 20] [--tabs 1 6] [--windows 6]
                                        [--fps 30] [--size 640x480]

Starts a real twin station (uvicorn in this process) and, per run, opens pages in headless
Chromium: 1 page is a pilot page; 6 pages are those of tests/test_video_tabs.py (pilot x3,
goggles x2, sessions). `--tabs` opens them as tabs of one browser context, as that test
does, and brings the first pilot page to the front: the tab the pilot looks at. The others
are background tabs, which a real browser hides (a hidden page is not streamed) and which
headless Chromium keeps "visible" but does not draw: it gives them animation frames in
bursts with a second between, and they draw as frames come at the pace a starved page
asks for (web/video.js).
`--windows` gives each page a context of its own, one window each, all shown. After a warm-up,
it collects for `--seconds` every front-camera frame each page shows (web/video.js
`cameras.log`, window.fpvDebug.cameras.log). The twin stamps each frame's render time
into its corner (companion/cameras/frame_stamp.py); the page reads it from the decoded
picture in the animation frame that shows it. Printed per run:

  render->screen   p50 / p99 ms: stamp to the animation frame that shows the picture
                   (the display shows it at its next refresh, up to one more refresh);
  station share    p50 / p99 ms: stamp until the page received the message (JPEG
                   encode, hand-off, fan-out, the socket; the stamp is taken when the
                   render is done); the rest is the browser's decode and wait for its
                   next animation frame;
  front tab        with tabs, the same figures for the tab in front alone;
  in turn          with tabs, then each video tab brought to the front in turn (as a
                   pilot switches tabs): 1 s after, its frames shown a second and its
                   largest VID over 3 s;
  frames shown per second per video page, the frames whose code did not read, and the
                   fewest animation frames per second a page was given;
  stages           p50 / p99 ms of the path, frame by frame: the JPEG encode and the
                   hand-off to the event loop (render stamp to the capture thread's
                   publish, seen by a listener on the camera's frames), the fan-out and
                   the socket into the page (publish to the page's message event), the
                   wait in the worker (for the camera's previous decode, or for the page
                   to draw one of the two pictures it holds), the decode, and the wait
                   for the animation frame that shows it;
  VID max          the largest video age the OSD of any page showed ("VID 0.3s"), and
                   per page;
  /api/status      p99 and largest time of the requests each page makes once a second
                   (`fetch`, from the call to the body read; one that had not answered by
                   the end counts with its age then), and how many.

Note the load average printed before each run: the figures are the whole machine's,
Chromium's pages and the station share its cores.
"""

from __future__ import annotations

import argparse
import collections
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from playwright.sync_api import BrowserContext, Page

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fpv_station.server.app import create_app  # noqa: E402
from tests.helpers import chromium, run_uvicorn, wait_until  # noqa: E402
from tests.pages import SIX_TABS as PAGES  # noqa: E402
from tests.twin_flights import twin_station_settings  # noqa: E402

VIDEO_PAGES = {"/", "/goggles.html"}
# Each video tab in front in turn: how long it is given to catch up, then measured.
TURN_SETTLE_MS = 1000
TURN_MS = 3000

# In every page from its first script: the largest VID age its OSD shows, its animation
# frames, and a GET /api/status once a second with its time. `__g2g.reset()` starts a count.
PROBE = """
(() => {
  const g = (window.__g2g = { vidMax: null, rafs: 0, api: [], open: new Map(), since: 0 });
  g.reset = () => { g.vidMax = null; g.rafs = 0; g.api = []; g.since = performance.now(); };
  const noteVid = (text) => {
    const m = /VID (\\d+(?:\\.\\d+)?)s/.exec(text || "");
    if (m) g.vidMax = Math.max(g.vidMax ?? 0, parseFloat(m[1]));
  };
  new MutationObserver((records) => {
    for (const r of records) {
      const node = r.target.nodeType === 1 ? r.target : r.target.parentElement;
      if (node && node.dataset && node.dataset.osd === "age") noteVid(node.textContent);
    }
  }).observe(document, { subtree: true, childList: true, characterData: true });
  const frame = () => { g.rafs += 1; requestAnimationFrame(frame); };
  requestAnimationFrame(frame);
  let id = 0;
  setInterval(() => {
    const key = ++id, start = performance.now();
    g.open.set(key, start);
    fetch("/api/status").then((r) => r.arrayBuffer().then(() => r.status)).then(
      (status) => { g.open.delete(key); if (start >= g.since) g.api.push({ ms: performance.now() - start, status }); },
      () => { g.open.delete(key); if (start >= g.since) g.api.push({ ms: performance.now() - start, status: 0 }); });
  }, 1000);
})();
"""

COLLECT = """() => {
  const g = window.__g2g, now = performance.now();
  const cams = window.fpvDebug && window.fpvDebug.cameras;
  const log = cams && cams.log ? cams.log : [];
  if (cams) cams.log = null;
  const open = [...g.open.values()].filter((s) => s >= g.since).map((s) => ({ ms: now - s, status: -1 }));
  return { log, vidMax: g.vidMax, rafPerS: g.rafs / ((now - g.since) / 1000), api: g.api.concat(open) };
}"""


def pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] if ordered else float("nan")


class Published:
    """When the capture thread published each front frame: a listener on the camera's
    `Latest[Frame]`, called in that thread (a bounded record, nothing more)."""

    def __init__(self) -> None:
        self.at: collections.deque[tuple[int, float, float]] = collections.deque(maxlen=20_000)

    def __call__(self, frame) -> None:
        self.at.append((frame.seq, frame.t_wall, time.time()))

    def by_seq(self) -> dict[int, tuple[float, float]]:
        return {seq: (t_wall, t_pub) for seq, t_wall, t_pub in list(self.at)}


def stages(stamped: list[dict], published: dict[int, tuple[float, float]]) -> dict:
    """Each stamped frame's time split by stage (ms), see the module docstring."""
    parts: dict[str, list[float]] = {k: [] for k in ("encode", "page", "wait", "decode", "raf")}
    for r in stamped:
        if "fromMs" not in r:
            continue  # a page without the stage times (an older web/video.js)
        if r["seq"] in published:  # the render stamp to the publish, then to the page
            encode = published[r["seq"]][1] * 1000 - r["fromMs"]
            parts["encode"].append(encode)
            parts["page"].append(r["stationMs"] - encode)
        parts["wait"].append(r["waitMs"])
        parts["decode"].append(r["decodeMs"])
        parts["raf"].append(r["totalMs"] - r["stationMs"] - r["waitMs"] - r["decodeMs"])
    return parts


def measure(
    base: str, browser, paths: list[str], windows: bool, seconds: float, published: Published
) -> dict:
    contexts: list[BrowserContext] = []
    pages: list[Page] = []
    for path in paths:
        if windows or not contexts:
            context = browser.new_context(viewport={"width": 1280, "height": 720})
            context.add_init_script(PROBE)
            contexts.append(context)
        page = contexts[-1].new_page()
        page.goto(base + path, timeout=120_000)
        pages.append(page)
    pages[0].bring_to_front()  # with tabs, the one the pilot looks at
    for page, path in zip(pages, paths, strict=True):
        if path in VIDEO_PAGES:
            page.wait_for_function(
                "() => window.fpvDebug && window.fpvDebug.cameras.frames.front", timeout=120_000
            )
    pages[0].wait_for_timeout(3000)  # warm-up: JIT, first layout, the twin's textures
    for page, path in zip(pages, paths, strict=True):
        start_count(page, path)
    pages[0].wait_for_timeout(seconds * 1000)
    got = [page.evaluate(COLLECT) for page in pages]
    turns = [] if windows or len(pages) == 1 else in_front_in_turn(pages, paths)
    for context in contexts:
        context.close()
    rows = [r for g in got for r in g["log"] if r["camera"] == "front"]
    stamped = [r for r in rows if r["kind"] == "render"]
    in_front = [
        r["totalMs"] for r in got[0]["log"] if r["camera"] == "front" and r["kind"] == "render"
    ]
    api = [a for g in got for a in g["api"]]
    video = [g for g, path in zip(got, paths, strict=True) if path in VIDEO_PAGES]
    return {
        "pages": len(paths),
        "frames": len(rows),
        "unread": len(rows) - len(stamped),
        "fps_per_page": len(rows) / max(1, len(video)) / seconds,
        "raf_min": min(g["rafPerS"] for g in got),
        "p50": pct([r["totalMs"] for r in stamped], 0.5),
        "p99": pct([r["totalMs"] for r in stamped], 0.99),
        "station_p50": pct([r["stationMs"] for r in stamped], 0.5),
        "station_p99": pct([r["stationMs"] for r in stamped], 0.99),
        "front": (len(in_front) / seconds, pct(in_front, 0.5), pct(in_front, 0.99)),
        "station_share": statistics.median(
            [r["stationMs"] / r["totalMs"] for r in stamped if r["totalMs"] > 0] or [float("nan")]
        ),
        "stages": stages(stamped, published.by_seq()),
        "vid_max": [(path, g["vidMax"]) for path, g in zip(paths, got, strict=True)],
        "turns": turns,
        "api_n": len(api),
        "api_failed": sum(1 for a in api if a["status"] != 200),
        "api_p99": pct([a["ms"] for a in api], 0.99),
        "api_max": max((a["ms"] for a in api), default=float("nan")),
    }


def start_count(page: Page, path: str) -> None:
    """The page's counts start now: its probe's and, on a video page, its frame log."""
    log = "window.fpvDebug.cameras.log = [];" if path in VIDEO_PAGES else ""
    page.evaluate(f"() => {{ {log} window.__g2g.reset(); }}")


def in_front_in_turn(pages: list[Page], paths: list[str]) -> list[tuple[str, float, float]]:
    """Each video tab brought to the front in turn, as a pilot switches tabs: after
    `TURN_SETTLE_MS`, its front frames shown a second and the largest VID its OSD shows
    over `TURN_MS`."""
    turns = []
    for page, path in zip(pages, paths, strict=True):
        if path not in VIDEO_PAGES:
            continue
        page.bring_to_front()
        page.wait_for_timeout(TURN_SETTLE_MS)
        start_count(page, path)
        page.wait_for_timeout(TURN_MS)
        g = page.evaluate(COLLECT)
        shown = sum(1 for r in g["log"] if r["camera"] == "front")
        turns.append((path, shown / (TURN_MS / 1000), g["vidMax"]))
    return turns


def report(name: str, r: dict, windows: bool) -> None:
    shown = [v for _, v in r["vid_max"] if v is not None]
    print(
        f"{name:>9} {r['frames']:>7} {r['fps_per_page']:>8.1f} {r['raf_min']:>7.1f} "
        f"{r['unread']:>6} {r['p50']:>7.1f} {r['p99']:>7.1f} "
        f"{r['station_p50']:>11.1f} {r['station_p99']:>11.1f} {r['station_share']:>6.0%} "
        f"{max(shown) if shown else float('nan'):>6.1f}s "
        f"{r['api_p99']:>7.0f} {r['api_max']:>7.0f} {r['api_n']:>4}"
        + (f" ({r['api_failed']} failed or unanswered)" if r["api_failed"] else "")
    )
    text = ", ".join(
        f"{name} {pct(v, 0.5):.1f} / {pct(v, 0.99):.1f}"
        for name, v in zip(
            ("encode", "to the page", "wait in the worker", "decode", "to the frame"),
            r["stages"].values(),
            strict=True,
        )
    )
    print(f"{'':>9} stages p50 / p99 ms: {text}")
    if r["pages"] > 1 and not windows:
        fps, p50, p99 = r["front"]
        print(f"{'':>9} front tab: {fps:.1f} frames a second, p50 {p50:.1f} ms, p99 {p99:.1f} ms")
    if r["turns"]:
        text = ", ".join(
            f"{path} {fps:.1f} fps VID {'--' if vid is None else f'{vid:.1f} s'}"
            for path, fps, vid in r["turns"]
        )
        print(f"{'':>9} each video tab in front in turn: {text}")
    if r["pages"] > 1:
        per_page = ", ".join(
            f"{path} {'--' if v is None else f'{v:.1f} s'}" for path, v in r["vid_max"]
        )
        print(f"{'':>9} VID max per page: {per_page}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--tabs", type=int, nargs="*", default=[1, 6], choices=[1, 6])
    ap.add_argument("--windows", type=int, nargs="*", default=[6], choices=[1, 6])
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--size", default="640x480", help="the cameras' frame size")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    overrides: dict = {"recording.auto_record_on_arm": False}
    for name in ("front", "bottom"):
        overrides |= {
            f"cameras.{name}.width": w,
            f"cameras.{name}.height": h,
            f"cameras.{name}.fps": args.fps,
        }
    runs = [(f"{n} tab{'s' * (n > 1)}", n, False) for n in args.tabs]
    runs += [(f"{n} window{'s' * (n > 1)}", n, True) for n in args.windows]
    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(twin_station_settings(Path(tmp), overrides))
        with run_uvicorn(app) as base, chromium() as browser:
            front = app.state.station.cameras["front"].frames
            wait_until(front.get, timeout=60)
            published = Published()
            front.add_listener(published)
            print(
                f"twin front+bottom cameras {w}x{h} at {args.fps:g} fps; {args.seconds:g} s "
                f"per run; ms from the render stamp; {os.cpu_count()} cores; 6 pages: "
                + " ".join(PAGES)
            )
            print(
                f"{'pages':>9} {'frames':>7} {'fps/page':>8} {'raf/s':>7} {'unread':>6} "
                f"{'p50':>7} {'p99':>7} {'station p50':>11} {'station p99':>11} {'share':>6} "
                f"{'VID max':>7} {'api p99':>7} {'api max':>7} {'n':>4}"
            )
            for name, n, windows in runs:
                load = os.getloadavg()
                print(f"{'':>9} load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
                paths = ["/"] if n == 1 else PAGES
                report(
                    name, measure(base, browser, paths, windows, args.seconds, published), windows
                )
    load = os.getloadavg()
    print(f"load average after {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")


if __name__ == "__main__":
    main()
