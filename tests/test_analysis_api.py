"""Analysis over REST through a real uvicorn: the same numbers as the CLI, PNG figures of
the right size, comparisons, and the one error shape for every bad request."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from fpv_station.analysis.plots import SIZE_PX
from fpv_station.server.app import create_app
from fpv_station.server.settings import load_settings
from tests import synthetic as syn
from tests.helpers import run_uvicorn

ROOT = Path(__file__).resolve().parents[1]
PHYSICAL, TWIN, NOFIX = syn.ANALYSIS_PHYSICAL, syn.ANALYSIS_TWIN, syn.ANALYSIS_NOFIX


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("analysis_api") / "sessions"
    real = syn.write_analysis_sessions(root)
    overrides = {
        "link.source": "none",
        "recording.sessions_dir": str(root),
        "recording.auto_record_on_arm": False,
        "recording.min_free_mb": 0,
    }
    app = create_app(load_settings(environ={}, overrides=overrides))
    lat, lon = real.point_llh(40.0, 0.0)
    with run_uvicorn(app) as base:
        yield base, root, f"{lat},{lon}"


def _png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def test_rest_and_cli_give_the_same_numbers(server, tmp_path):
    base, root, ref = server
    r = httpx.get(
        f"{base}/api/sessions/{PHYSICAL}/analysis",
        params={"task": "a-to-b", "reference": ref},
        timeout=120,
    )
    assert r.status_code == 200, r.text
    rest = r.json()
    assert rest["sessions"] == [PHYSICAL] and rest["task"] == "a-to-b"
    assert rest["results"][0]["lateral_deviation_m"] == pytest.approx(0.5 / 2**0.5, rel=0.01)

    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-m",
        "fpv_station.server",
        "analyze",
        str(root / PHYSICAL),
        "--task",
        "a-to-b",
        "--reference",
        ref,
        "--out",
        str(out),
    ]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    cli = json.loads((out / "a-to-b_table.json").read_text())
    for got, want in zip(rest["results"], cli["results"], strict=True):
        got.pop("source"), want.pop("source")
        assert got == want  # every metric, to the last bit
    assert rest["columns"] == cli["columns"]


def test_plots_as_png(server):
    base, _, ref = server
    for plot in ("trajectory3d", "birdseye", "history"):
        r = httpx.get(
            f"{base}/api/sessions/{PHYSICAL}/analysis/{plot}.png",
            params={"task": "a-to-b", "reference": ref},
            timeout=120,
        )
        assert r.status_code == 200 and r.headers["content-type"] == "image/png"
        assert _png_size(r.content) == SIZE_PX


def test_comparison_of_physical_and_twin(server):
    base, _, ref = server
    params = {"task": "a-to-b", "reference": ref, "sessions": [TWIN, PHYSICAL]}
    r = httpx.get(f"{base}/api/analysis", params=params, timeout=120)
    assert r.status_code == 200, r.text
    results = r.json()["results"]
    assert [x["platform"] for x in results] == ["physical", "twin"]
    assert results[1]["lateral_deviation_m"] == pytest.approx(1 / 2**0.5, rel=0.01)
    png = httpx.get(f"{base}/api/analysis/history.png", params=params, timeout=120)
    assert png.status_code == 200 and _png_size(png.content) == SIZE_PX


def test_thresholds_are_parameters(server):
    """The hover window of an A-to-B flight flown at 3 m happens at 2.5 m."""
    base, _, _ = server
    r = httpx.get(
        f"{base}/api/sessions/{PHYSICAL}/analysis",
        params={"task": "hover", "hover_height_m": 2.5, "hover_window_s": 5},
        timeout=120,
    )
    assert r.status_code == 200, r.text
    assert r.json()["results"][0]["time_in_window_s"] == pytest.approx(5.0, abs=0.11)


def test_parallel_requests_all_answer_and_the_station_stays_up(server):
    """Analyses queue behind one another in worker threads; health still answers."""
    from concurrent.futures import ThreadPoolExecutor

    base, _, ref = server
    urls = [
        f"{base}/api/sessions/{sid}/analysis/{plot}.png"
        for sid in (PHYSICAL, TWIN)
        for plot in ("trajectory3d", "birdseye")
    ]
    with ThreadPoolExecutor(4) as pool:
        pending = [
            pool.submit(httpx.get, u, params={"task": "a-to-b", "reference": ref}, timeout=60)
            for u in urls
        ]
        health = httpx.get(f"{base}/api/health", timeout=10)
        replies = [p.result() for p in pending]
    assert health.status_code == 200
    assert [r.status_code for r in replies] == [200] * 4
    assert all(_png_size(r.content) == SIZE_PX for r in replies)


def test_analysis_page_in_chromium(server):
    """The page lists the sessions, shows the paper's table and the three figures, and
    shows the API's error text for a task whose window never happens."""
    from urllib.parse import urlencode

    from playwright.sync_api import expect

    from tests.helpers import chromium

    base, _, ref = server
    q = urlencode(
        [("task", "a-to-b"), ("sessions", PHYSICAL), ("sessions", TWIN), ("reference", ref)]
    )
    with chromium() as browser:
        page = browser.new_page()
        page.goto(f"{base}/analysis.html?{q}")
        rows = page.locator("#table tbody tr")
        expect(rows).to_have_count(2, timeout=30_000)
        expect(rows.nth(0)).to_contain_text("Physical quadcopter")
        expect(rows.nth(1)).to_contain_text("Digital twin")
        expect(rows.nth(1)).to_contain_text("0.707")
        page.wait_for_function(
            "[...document.querySelectorAll('#figures img')].length === 3 && "
            "[...document.querySelectorAll('#figures img')].every(i => i.complete && "
            f"i.naturalWidth === {SIZE_PX[0]})",
            timeout=60_000,
        )
        page.select_option("#task", "hover")
        page.click("button[type=submit]")
        expect(page.locator("#error")).to_contain_text("NoTaskWindow", timeout=30_000)
