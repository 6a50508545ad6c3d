"""The flight task in headless Chromium against the twin: the pilot picks task 1 on the page, the
scripted pilot flies it through the page's own control path (`WS /ws/control` sticks),
the procedure's steps light up in order, the map shows the vehicle on the start pad, and
the trial's score appears after landing (the station's own analysis of the session)."""

from __future__ import annotations

import json
import threading
import time

import httpx
import numpy as np
import pytest
from playwright.sync_api import expect
from websockets.sync.client import connect

from fpv_station.twin.pilot import Leg, Observation, Pilot, task_plan
from tests.twin_flights import task_page_on_the_twin


def fly_over_the_control_socket(ws_url: str, twin, pilot: Pilot, stop: threading.Event) -> None:
    """The scripted pilot's sticks at 50 Hz, as the page's gamepad would send them."""
    with connect(f"{ws_url}/ws/control") as ws:
        assert json.loads(ws.recv(timeout=5))["type"] == "hello"
        while not pilot.done and not stop.is_set():
            with twin.lock:
                sim = twin.sim
                pose = sim.pose()
                armed = bool(sim.commander.armed[0])
            yaw = float(np.arctan2(pose.R_world_body[1, 0], pose.R_world_body[0, 0]))
            roll, pitch, yaw_stick, thr = pilot.update(
                Observation(pose.t_s, pose.pos_enu_m, pose.vel_enu_mps, yaw, armed)
            )
            ws.send(
                json.dumps(
                    {
                        "type": "sticks",
                        "roll": roll,
                        "pitch": pitch,
                        "yaw": yaw_stick,
                        "throttle": thr,
                    }
                )
            )
            time.sleep(0.02)


@pytest.mark.timeout(240)
def test_pilot_flies_task_1_with_procedure_map_and_score(tmp_path, browser):
    with task_page_on_the_twin(browser, tmp_path, 1) as (app, base, page):
        station = app.state.station
        twin = station.twin
        steps = page.locator("#task-steps li")
        expect(steps).to_have_text(
            ["Armed", "Took off", "Reached 4 m", "Held 10 s", "Landed", "Disarmed"]
        )
        expect(page.locator("#task-procedure li").first).to_contain_text("Arm on the start pad")
        assert httpx.get(f"{base}/api/task").json()["selected"]["id"] == 1
        # The map: the vehicle drawn on the start pad (x = -20 m, y = 0) before take-off.
        x, y = map(float, page.locator("#task-map").get_attribute("data-vehicle").split(","))
        assert abs(x + 20.0) < 1.0 and abs(y) < 1.0

        legs = task_plan(twin.scene, 1)
        legs.insert(1, Leg("hold", alt_m=0.0, seconds=1.5))  # recording starts at the armed beat
        pilot = Pilot(legs, descent_mps=1.0)  # the vehicle's limit is 1.5 m/s
        stop = threading.Event()
        flyer = threading.Thread(
            target=fly_over_the_control_socket,
            args=(base.replace("http", "ws"), twin, pilot, stop),
        )
        flyer.start()
        try:
            seen: list[int] = []  # the highlighted step, as it changes
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                current = page.evaluate(
                    "(document.querySelector('#task-steps li.current') || {dataset: {}})"
                    ".dataset.step"
                )
                step = int(current) if current is not None else 6  # all done
                if not seen or seen[-1] != step:
                    seen.append(step)
                if step == 6:
                    break
                page.wait_for_timeout(200)
        finally:
            stop.set()
            flyer.join(10)
        assert pilot.done, pilot.log
        # In order, each step once: armed -> took off -> 4 m -> held -> landed -> disarmed.
        assert seen == sorted(seen) and seen[-1] == 6, seen
        assert {1, 2, 3, 4, 5} <= set(seen), seen
        assert page.locator("#task-steps li.done").count() == 6
        # Scored once the session closed: the station's own analysis, on the page.
        result = page.locator("#task-result")
        expect(result).to_contain_text("hover", timeout=60_000)
        score = httpx.get(f"{base}/api/task").json()["last_score"]
        assert score["ok"], score
        hover = score["result"]["hover_distance_m"]
        expect(result).to_contain_text(f"{hover:.3f} m")
        assert hover < 0.5
        expect(page.locator("#task-attempts li")).to_have_count(1)
        # The sessions page shows the task and the score of the session.
        page.goto(f"{base}/sessions.html")
        row = page.locator("#sessions tbody tr").first
        expect(row.locator("td.task")).to_have_text("1. Take off, hover, land")
        expect(row.locator("td.score")).to_contain_text(f"hover {hover:.3f} m")
