"""The twin, flown through each of the paper's four tasks by its scripted pilot, sends
real MAVLink over UDP; a tlog recorder on the other socket makes a session of it; the
sessions analyse without error and with plausible values."""

from __future__ import annotations

import json
import socket
from pathlib import Path

import numpy as np
import pytest

from fpv_station.analysis.report import analyze_paths
from fpv_station.core.mavlink.tlog_records import encode_record
from fpv_station.twin.pilot import Observation, Pilot, task_plan
from fpv_station.twin.runner import Twin
from tests.helpers import wait_until

# The module's fixture flies four tasks; on a loaded CI machine that outlasts the
# suite's default hang guard.
pytestmark = pytest.mark.timeout(600)
TASKS = {1: "hover", 2: "a-to-b", 3: "obstacle", 4: "figure8"}
WALL_T0 = 1.76e9
TICK_S = 0.02  # the pilot's 50 Hz


def fly_to_session(task_id: int, folder: Path, timeout_s: float = 300.0) -> Path:
    """Step the twin faster than real time; every datagram it sends is written to the
    session's mavlink.tlog stamped with the sim clock, as the recorder stamps receive time."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.setblocking(False)
    # No flight log of its own (a ULog at the physics rate): only the MAVLink is recorded.
    twin = Twin(mavlink=f"udpout:127.0.0.1:{rx.getsockname()[1]}", flight_log=False)
    folder.mkdir(parents=True)
    pilot = Pilot(task_plan(twin.scene, task_id))
    try:
        with open(folder / "mavlink.tlog", "wb") as tlog:

            def drain() -> None:
                while True:
                    try:
                        data = rx.recv(65535)
                    except BlockingIOError:
                        return
                    tlog.write(encode_record(WALL_T0 + twin.sim.t_s, data))

            for _ in range(int(2.5 / TICK_S)):  # on the pad until the GPS has a fix
                twin.step_for(TICK_S)
                drain()
            t0 = twin.sim.t_s
            while not pilot.done and twin.sim.t_s - t0 < timeout_s:
                pose = twin.pose()
                assert not twin.sim.state.crash[0], twin.sim.crash_reason()
                yaw = float(np.arctan2(pose.R_world_body[1, 0], pose.R_world_body[0, 0]))
                armed = bool(twin.sim.commander.armed[0])
                obs = Observation(pose.t_s, pose.pos_enu_m, pose.vel_enu_mps, yaw, armed)
                twin.set_sticks(*pilot.update(obs))
                twin.step_for(TICK_S)
                drain()
            for _ in range(int(3.0 / TICK_S)):  # the tail after landing, as recorded
                twin.step_for(TICK_S)
                drain()
    finally:
        if twin.vehicle is not None:
            twin.vehicle.close()
        rx.close()
    assert pilot.done, f"task {task_id}: the pilot did not finish: {pilot.log[-3:]}"
    (folder / "session.json").write_text(json.dumps({"source": "sim"}))
    return folder


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("twin_sessions")
    return {name: fly_to_session(k, root / f"task{k}") for k, name in TASKS.items()}


def test_twin_hover(sessions):
    an = analyze_paths([sessions["hover"]], "hover")
    r = an.results[0]
    assert r.platform == "twin" and an.aligned[0].reference_kind == "scene"
    assert r.hover_distance_m < 0.5  # no wind: Position mode holds over the pad
    # The window is 10 s, measured between GPS samples (10 Hz): at most one period short.
    assert 9.85 <= r.time_in_window_s <= 10.5 and 15 < r.trial_time_s < 120
    # The scripted pilot climbs through 4 m as a person does, so the paper's literal
    # window (from the first time the altitude reaches 4 m) is the hold.
    assert r.height_deviation_m < 0.3


@pytest.mark.parametrize("task", ["a-to-b", "obstacle", "figure8"])
def test_twin_longitudinal_tasks(sessions, task):
    an = analyze_paths([sessions[task]], task)
    r = an.results[0]
    assert r.platform == "twin" and an.aligned[0].reference_kind == "scene"
    assert r.obstacle_contacts == 0  # the pilot flies over and around, never into them
    assert r.height_deviation_m < 1.0 and 20 < r.trial_time_s < 300
    # The straight task stays near the line; circling and the 8 swing metres off it.
    assert r.lateral_deviation_m < 1.0 if task == "a-to-b" else 0.5 < r.lateral_deviation_m < 8
    assert r.path_length_m > 36 and 0.3 < r.mean_speed_mps < 5


def test_twin_and_synthetic_physical_compare_in_one_table(sessions):
    an = analyze_paths([sessions["a-to-b"], sessions["a-to-b"]], "a-to-b", labels=["a", "b"])
    assert len(an.comparison.rows()) == 2
    assert "Digital twin" in an.comparison.to_markdown()


def test_station_on_the_twin_records_a_hover_that_analyses_over_rest(tmp_path):
    """End to end: `--source sim` station, the pilot picks task 1 (POST /api/task), the
    scripted pilot flies it, the recorder starts on arming and stops after landing, the
    station scores the trial on its own, and that score is what the REST analysis and
    `fpv-station analyze --task hover` give for the session."""
    import httpx

    from fpv_station.server.cli import main as cli_main
    from tests.twin_flights import NO_CAMERAS, recorded_twin_flight

    def choose_task_1(base: str) -> None:
        r = httpx.post(f"{base}/api/task", json={"task_id": 9}, timeout=5)
        assert r.status_code == 400 and "No task 9" in r.json()["error_msg"]
        r = httpx.post(f"{base}/api/task", json={"task_id": 1}, timeout=5)
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["selected"]["name"] == "Take off, hover, land"
        assert body["paper"]["twin"]["hover_distance_m"] == 0.1056

    # Real time (viser off, cameras off): the recorder stamps wall time.
    overrides = NO_CAMERAS
    with recorded_twin_flight(tmp_path, 1, overrides, before_flight=choose_task_1) as flight:
        r = httpx.get(
            f"{flight.base_url}/api/sessions/{flight.session_id}/analysis",
            params={"task": "hover"},
            timeout=60,
        )
        assert wait_until(lambda: httpx.get(f"{flight.base_url}/api/task").json()["last_score"], 60)
        task = httpx.get(f"{flight.base_url}/api/task").json()
        listed = httpx.get(f"{flight.base_url}/api/sessions").json()
    assert r.status_code == 200, r.text
    res = r.json()["results"][0]
    assert res["platform"] == "twin" and res["reference_kind"] == "scene"
    assert res["hover_distance_m"] < 0.5 and res["window_samples"] >= 40  # 5 Hz GPS, 10 s
    assert 10 < res["trial_time_s"] < 60 and res["obstacle_contacts"] == 0
    assert res["height_deviation_m"] < 0.5
    # Flown to the letter: a valid trial, landed on the start pad near its centre.
    assert res["valid"] and res["invalid_reasons"] == [] and res["landing_pad"] == "start"
    assert res["landing_accuracy_m"] < 0.75
    # Scored on landing, with the same reader and clock: every figure of REST and the CLI,
    # to the bit (the session's measured vehicle clock places the samples for all three).
    score = task["last_score"]
    assert task["last_session"] == flight.session_id and score["ok"] and score["task"] == "hover"
    figures = {k: v for k, v in score["result"].items() if k != "source"}
    assert {k: v for k, v in res.items() if k != "source"} == figures
    out = tmp_path / "cli"
    assert cli_main(["analyze", "--task", "hover", str(flight.folder), "--out", str(out)]) == 0
    cli = json.loads((out / "hover_table.json").read_text())
    cli_row = cli["results"][0] if isinstance(cli, dict) else cli[0]
    assert {k: v for k, v in cli_row.items() if k != "source"} == figures
    assert [a["session"] for a in task["attempts"]] == [flight.session_id]
    # The session knows its task and its score; the sessions list shows both.
    meta = json.loads((flight.folder / "session.json").read_text())
    assert meta["task"]["id"] == 1 and meta["task"]["analysis"] == "hover"
    assert meta["score"]["result"]["hover_distance_m"] == score["result"]["hover_distance_m"]
    row = next(s for s in listed if s["id"] == flight.session_id)
    assert row["task"]["name"] == "Take off, hover, land" and row["score"]["ok"]


def test_an_aborted_trial_says_why(tmp_path):
    """Task 1 chosen, but the pilot lands from 2 m: no score, and the reason in words."""
    import httpx

    from fpv_station.twin.pilot import Leg
    from tests.twin_flights import NO_CAMERAS, recorded_twin_flight

    def choose(base: str) -> None:
        assert httpx.post(f"{base}/api/task", json={"task_id": 1}).status_code == 200

    legs = [Leg("arm"), Leg("climb", alt_m=2.0), Leg("hold", alt_m=2.0, seconds=2.0), Leg("land")]
    overrides = NO_CAMERAS
    with recorded_twin_flight(tmp_path, 1, overrides, before_flight=choose, legs=legs) as flight:
        assert wait_until(lambda: httpx.get(f"{flight.base_url}/api/task").json()["last_score"], 60)
        score = httpx.get(f"{flight.base_url}/api/task").json()["last_score"]
    assert score["ok"] is False and "never reached 4 m" in score["reason"]
