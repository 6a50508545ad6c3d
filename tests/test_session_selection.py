"""Sessions selected by task, pilot and score: the sessions page's REST selection and
`fpv-station export --select` take the same sessions from the same folder; failed trials
(by the score stored at the disarm) are left out unless asked for; the REST export of a
selection runs off the station's process and downloads as a zip; `learn eval --demos`
gives human and scripted demonstrations rows of their own.

The folder: two scripted twin demonstrations of task 1 (`learn.demos`, each scored as at
the disarm: seed 7 valid, seed 8 not, its hover under 4 m), retagged as two human pilots'
attempts and kept as scripted, in copies of the real session folders."""

from __future__ import annotations

import io
import json
import shutil
import time
import zipfile
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import expect

from fpv_station.companion.recording.meta import Demonstration, read_meta, write_meta
from fpv_station.learn.evaluate import demonstration_rows
from fpv_station.server.app import create_app
from fpv_station.server.cli import main as cli_main
from tests.demo_flights import shared_demo
from tests.helpers import run_uvicorn, station_settings


def _retag(src: Path, root: Path, sid: str, kind: str, pilot: str, attempt: int) -> Path:
    folder = root / sid
    shutil.copytree(src, folder)
    path = folder / "session.json"
    meta = read_meta(path)
    tag = Demonstration(kind=kind, pilot=pilot, run="r", attempt=attempt, attempts=2)
    write_meta(path, meta.model_copy(update={"id": sid, "demonstration": tag}))
    return folder


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> Path:
    valid, failed = shared_demo(tmp_path_factory, 7), shared_demo(tmp_path_factory, 8)
    tag = read_meta(valid / "session.json").demonstration  # as the twin's pilot flew it
    assert tag is not None
    assert (tag.kind, tag.pilot, tag.attempt, tag.attempts) == ("scripted", "scripted", 1, 1)
    score = read_meta(valid / "session.json").score
    assert score is not None and score.result is not None and score.result["valid"] is True
    score = read_meta(failed / "session.json").score
    assert score is not None and score.ok is False  # never reached 4 m
    root = tmp_path_factory.mktemp("sessions")
    _retag(valid, root, "20261201T100000Z_sim", "human", "Ana", 1)
    _retag(failed, root, "20261201T100100Z_sim", "human", "Ana", 2)
    _retag(valid, root, "20261201T110000Z_sim", "human", "Ben", 1)
    _retag(valid, root, "20261201T120000Z_sim", "scripted", "scripted", 1)
    return root


ANA_OK, ANA_FAILED, BEN, SCRIPTED = (
    "20261201T100000Z_sim",
    "20261201T100100Z_sim",
    "20261201T110000Z_sim",
    "20261201T120000Z_sim",
)
CASES = [
    ("task=1", False, [ANA_OK, BEN, SCRIPTED]),
    ("task=1", True, [ANA_OK, ANA_FAILED, BEN, SCRIPTED]),
    ("task=1,pilot=ana", False, [ANA_OK]),  # names match whatever their case
    ("pilot=Ana", True, [ANA_OK, ANA_FAILED]),
    ("kind=human", False, [ANA_OK, BEN]),
    ("kind=scripted", False, [SCRIPTED]),
    ("task=2", True, []),
    ("task=1,hover_distance_m<=0.01", False, []),
    ("task=1,hover_distance_m<=5", False, [ANA_OK, BEN, SCRIPTED]),
]


def _cli_list(capsys, root: Path, select: str, include_failed: bool) -> list[str]:
    argv = ["export", "--select", select, "--sessions-dir", str(root), "--list"]
    assert cli_main(argv + (["--include-failed"] if include_failed else [])) == 0
    return capsys.readouterr().out.split()


def test_rest_and_cli_select_the_same_sessions(sessions: Path, capsys):
    app = create_app(station_settings("none", sessions))
    with run_uvicorn(app) as base:
        for select, include_failed, expected in CASES:
            reply = httpx.get(
                f"{base}/api/selection",
                params={"select": select, "include_failed": include_failed},
                timeout=10,
            ).json()
            assert reply["sessions"] == expected, (select, include_failed)
            assert _cli_list(capsys, sessions, select, include_failed) == expected
        # Left out, and why: the failed trial's own reason, from its score.
        reply = httpx.get(f"{base}/api/selection", params={"select": "pilot=Ana"}).json()
        assert list(reply["failed"]) == [ANA_FAILED]
        assert "never reached 4 m" in reply["failed"][ANA_FAILED]
        # Bad selections: a clear 400 (REST) or exit 2 (CLI), never a crash.
        for bad in (
            "foo=1",
            "task=x",
            "task=\u00b2",
            "kind=robot",
            "pilot=a/b",
            "speed<=1",
            "task=1,,x",
        ):
            r = httpx.get(f"{base}/api/selection", params={"select": bad})
            assert r.status_code == 400 and r.json()["error"] == "BadRequest", bad
            argv = ["export", "--select", bad, "--sessions-dir", str(sessions), "--list"]
            assert cli_main(argv) == 2, bad
            assert "fpv-station export:" in capsys.readouterr().err


@pytest.mark.timeout(240)
def test_rest_export_of_a_selection(sessions: Path, tmp_path: Path):
    root = tmp_path / "sessions"
    shutil.copytree(sessions, root)
    app = create_app(station_settings("none", root))
    with run_uvicorn(app) as base:
        api = httpx.Client(base_url=base, timeout=10)
        assert (
            api.post("/api/exports", json={"select": "task=1", "format": "csv"}).status_code == 422
        )
        assert api.post("/api/exports", json={"select": "speed<=1"}).status_code == 400
        r = api.post("/api/exports", json={"select": "task=2", "format": "lerobot"})
        assert r.status_code == 400 and "No session" in r.json()["error_msg"]
        r = api.post("/api/exports", json={"select": "pilot=Ana", "format": "lerobot"})
        assert r.status_code == 202, r.text
        record = r.json()
        assert record["sessions"] == [ANA_OK] and record["left_out_failed"] == 1
        deadline = time.monotonic() + 200  # a hang guard
        while record["state"] == "running" and time.monotonic() < deadline:
            time.sleep(0.5)
            record = api.get(f"/api/exports/{record['id']}").json()
        assert record["state"] == "done", record
        assert record["episodes"] == 1 and record["frames"] > 0
        assert [e["id"] for e in api.get("/api/exports").json()] == [record["id"]]
        # Where it went: the sessions folder's exports/<id>/, with its record beside it.
        folder = root / "exports" / record["id"]
        assert json.loads((folder / "export.json").read_text())["select"] == "pilot=Ana"
        z = zipfile.ZipFile(io.BytesIO(api.get(f"/api/exports/{record['id']}/download").content))
        info = json.loads(z.read(f"{record['id']}/lerobot/meta/info.json"))
        assert info["total_episodes"] == 1
        assert api.get("/api/exports/nope").status_code == 404
        assert api.get("/api/exports/20990101T000000Z/download").status_code == 404


def test_eval_rows_by_who_flew(sessions: Path):
    paths = sorted(p for p in sessions.iterdir() if p.is_dir())
    rows = demonstration_rows(paths, 1)
    assert [(r.name, len(r.outcomes)) for r in rows] == [
        ("human demonstrations (Ana)", 2),
        ("human demonstrations (Ben)", 1),
        ("scripted demonstrations", 1),
    ]
    one_pilot = demonstration_rows([sessions / ANA_OK, sessions / SCRIPTED], 1)
    assert [r.name for r in one_pilot] == ["human demonstrations", "scripted demonstrations"]


@pytest.mark.timeout(240)
def test_sessions_page_selects_and_exports(sessions: Path, tmp_path: Path, browser):
    root = tmp_path / "sessions"
    shutil.copytree(sessions, root)
    app = create_app(station_settings("none", root))
    with run_uvicorn(app) as base:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(f"{base}/sessions.html")
        rows = page.locator("#sessions tbody tr")
        expect(rows).to_have_count(4)
        page.fill("#sel-pilot", "Ana")
        page.click("#sel-apply")
        expect(rows).to_have_count(1)
        expect(rows.first).to_have_attribute("data-id", ANA_OK)
        expect(rows.first.locator("td.pilot")).to_have_text("Ana (1/2)")
        expect(page.locator("#sel-count")).to_contain_text(
            "1 session selected (pilot=Ana); 1 failed trial left out"
        )
        page.check("#sel-failed")
        page.click("#sel-apply")
        expect(rows).to_have_count(2)
        page.uncheck("#sel-failed")
        page.click("#sel-apply")
        expect(rows).to_have_count(1)
        page.click("#export-start")
        expect(page.locator("#export-download")).to_be_visible(timeout=200_000)
        record = httpx.get(f"{base}/api/exports", timeout=10).json()[0]
        assert record["state"] == "done" and record["sessions"] == [ANA_OK]
        page.click("#sel-clear")
        expect(rows).to_have_count(4)
