"""Demonstration mode on the pilot page, in headless Chromium against the twin: the pilot
starts a run of 2 attempts at task 1 from the header's drop-down; each arm/disarm of the
twin (over `/ws/control`, as the page's Arm and Disarm) is one recorded session tagged
with the pilot's name and `human`; the page shows attempt k of N, keeps it over a reload
(the run is the server's), and the run ends by itself after the second attempt. The REST
refusals: bad names and counts, no task chosen, a task change during the run."""

from __future__ import annotations

import json

import httpx
import pytest
from playwright.sync_api import expect
from websockets.sync.client import connect

from fpv_station.companion.recording.meta import read_meta
from fpv_station.server.app import create_app
from tests.helpers import run_uvicorn, station_settings, wait_until
from tests.twin_flights import NO_CAMERAS, twin_station_settings


def _command(ws, cmd: str, tries: int = 40) -> None:
    """Send an arm or disarm until the twin accepts it: it refuses to arm without a fix,
    and the station refuses any command before it has heard the twin's autopilot."""
    for _ in range(tries):
        ws.send(json.dumps({"type": cmd}))
        while True:
            reply = json.loads(ws.recv(timeout=10))
            if (reply.get("type") == "ack" and reply.get("cmd") == cmd) or "error" in reply:
                break
        if reply.get("ok"):
            return
        wait_until(lambda: False, timeout=0.5)
    raise AssertionError(f"the twin refused {cmd}: {reply}")


def _attempt(base: str, station, page, k: int) -> None:
    """Arm, wait for the page to show attempt k recorded, disarm; the session ends."""
    recorder = station.recorder
    with connect(base.replace("http", "ws") + "/ws/control") as ws:
        assert json.loads(ws.recv(timeout=10))["type"] == "hello"
        _command(ws, "arm")
        assert wait_until(lambda: recorder.session is not None, timeout=15)
        expect(page.locator("#demo-summary")).to_contain_text(f"attempt {k} of 2 REC")
        _command(ws, "disarm")
    assert wait_until(lambda: recorder.session is None, timeout=15)


@pytest.mark.timeout(180)
def test_demonstration_run_on_the_pilot_page(tmp_path, browser):
    settings = twin_station_settings(tmp_path, {**NO_CAMERAS, "recording.post_disarm_tail_s": 0.2})
    app = create_app(settings)
    with run_uvicorn(app) as base:
        station = app.state.station
        api = httpx.Client(base_url=base, timeout=10)
        # Refused: no task chosen yet, and bad names or counts.
        r = api.post("/api/demo", json={"pilot": "Ana Lu", "attempts": 2})
        assert r.status_code == 409 and "task" in r.json()["error_msg"]
        for bad in (
            {"pilot": "a,b", "attempts": 2},
            {"pilot": "", "attempts": 2},
            {"pilot": "x" * 41, "attempts": 2},
            {"pilot": "Ana", "attempts": 0},
            {"pilot": "Ana", "attempts": 51},
            {"pilot": "<b>", "attempts": 1},
        ):
            assert api.post("/api/demo", json=bad).status_code == 422, bad
        assert api.get("/api/demo").json()["run"] is None
        assert api.post("/api/task", json={"task_id": 1}).status_code == 200

        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(f"{base}/")
        page.click("#demo-summary")
        page.fill("#demo-pilot", "Ana Lu")
        page.fill("#demo-attempts", "2")
        page.click("#demo-start")
        expect(page.locator("#demo-summary")).to_have_text("DEMO Ana Lu: attempt 1 of 2")
        # The run holds its task.
        r = api.post("/api/task", json={"task_id": 2})
        assert r.status_code == 409 and "Ana Lu" in r.json()["error_msg"]
        assert api.post("/api/demo", json={"pilot": "Ben", "attempts": 1}).status_code == 409

        _attempt(base, station, page, 1)
        expect(page.locator("#demo-summary")).to_have_text("DEMO Ana Lu: attempt 2 of 2")
        page.reload()  # the run is the server's
        expect(page.locator("#demo-summary")).to_have_text("DEMO Ana Lu: attempt 2 of 2")
        page.click("#demo-summary")
        expect(page.locator("#demo-flown li")).to_have_count(1)

        _attempt(base, station, page, 2)
        expect(page.locator("#demo-summary")).to_have_text("Demo")
        expect(page.locator("#demo-status")).to_contain_text("2 of 2 flown")
        expect(page.locator("#demo-flown li")).to_have_count(2)
        reply = api.get("/api/demo").json()
        assert not reply["active"] and reply["run"]["ended"] == "all 2 attempts flown"
        sessions = reply["run"]["sessions"]
        assert [a["session"] for a in reply["flown"]] == sessions
        # Each attempt's session.json says who flew it, the run and the attempt.
        tags = [read_meta(tmp_path / s / "session.json") for s in sessions]
        assert [(m.demonstration.kind, m.demonstration.pilot) for m in tags] == [
            ("human", "Ana Lu")
        ] * 2
        assert [m.demonstration.attempt for m in tags] == [1, 2]
        assert {m.demonstration.run for m in tags} == {reply["run"]["run"]}
        assert {m.task.id for m in tags} == {1}
        # A session now is no attempt of the ended run.
        assert station.recorder.demonstration is None
        assert api.post("/api/task", json={"task_id": 2}).status_code == 200


def test_a_run_outlives_a_restart_unless_its_task_changed(tmp_path):
    def station_reply(method: str = "GET", path: str = "/api/demo", **kw) -> dict:
        with run_uvicorn(create_app(station_settings("none", tmp_path))) as base:
            if method != "GET":
                assert httpx.request(method, base + path, timeout=10, **kw).status_code == 200
            return httpx.get(base + "/api/demo", timeout=10).json()

    station_reply("POST", "/api/task", json={"task_id": 3})
    started = station_reply("POST", json={"pilot": "Ana", "attempts": 4})
    assert started["active"] and started["attempt"] == 1
    again = station_reply()  # a new station on the same sessions folder
    assert again["active"] and again["run"] == started["run"]
    # The task file now names another task (as if chosen elsewhere): the run ends.
    chosen = tmp_path / "chosen_task.json"
    chosen.write_text(json.dumps({**json.loads(chosen.read_text()), "task_id": 1}))
    ended = station_reply()
    assert not ended["active"] and "task changed" in ended["run"]["ended"]
    assert station_reply("POST", "/api/task", json={"task_id": 2})["run"] == ended["run"]
