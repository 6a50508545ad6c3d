"""The station on the twin (`serve --source sim`): the real link over loopback UDP, and the
browser's sticks over `WS /ws/control` turned into MANUAL_CONTROL."""

from __future__ import annotations

import json
import time

import pytest
from websockets.sync.client import connect

from fpv_station.server.app import create_app
from fpv_station.server.settings import load_settings
from tests.helpers import run_uvicorn, wait_until
from tests.twin_flights import NO_CAMERAS


def sim_app(**overrides):
    settings = load_settings(
        None,
        {
            "link.source": "sim",
            "twin.realtime_factor": 2.0,
            "recording.auto_record_on_arm": False,
            "viser.enabled": False,
            **NO_CAMERAS,
            **overrides,
        },
        environ={},
    )
    return create_app(settings)


@pytest.fixture()
def station_url(tmp_path):
    app = sim_app(**{"recording.sessions_dir": str(tmp_path)})
    with run_uvicorn(app) as url:
        yield app, url.replace("http", "ws")


def state(app):
    latest = app.state.station.state.get()
    return latest.value if latest else None


def test_station_follows_the_twin_and_browser_sticks_fly_it(station_url) -> None:
    app, ws_url = station_url
    twin = app.state.station.twin
    assert wait_until(lambda: state(app) and state(app).gps.fix_type == 3, timeout=10)
    assert state(app).heartbeat.autopilot == "px4" and state(app).heartbeat.mode == "POSCTL"
    with connect(ws_url + "/ws/control") as ws:
        hello = json.loads(ws.recv(timeout=5))
        assert hello["type"] == "hello" and hello["deadman_s"] == 0.5
        ws.send(json.dumps({"type": "arm"}))
        reply = json.loads(ws.recv(timeout=5))  # what the vehicle answered, not what we sent
        assert (reply["type"], reply["cmd"], reply["ok"], reply["result"]) == (
            "ack",
            "arm",
            True,
            "ACCEPTED",
        )
        assert wait_until(lambda: state(app).heartbeat.armed, timeout=5)
        deadline = time.monotonic() + 10
        while twin.pose().pos_enu_m[2] < 2.0:  # full climb stick, as a gamepad sends it
            ws.send(
                json.dumps({"type": "sticks", "roll": 0, "pitch": 0, "yaw": 0, "throttle": 1.0})
            )
            time.sleep(0.02)
            assert time.monotonic() < deadline, "the twin did not climb"
        assert state(app).rc.pwm_us[2] > 1900  # the station sees the stick as RC PWM
        assert max(state(app).servo.pwm_us[:4]) > 1300
        # Dead-man: the browser goes silent; after 0.5 s the sticks are centred and
        # Position mode holds the altitude.
        time.sleep(1.5)
        z0 = twin.pose().pos_enu_m[2]
        time.sleep(1.0)
        assert abs(twin.pose().pos_enu_m[2] - z0) < 0.3
        assert abs(twin.pose().vel_enu_mps[2]) < 0.3
        assert state(app).rc.pwm_us[2] == 1500
        # A disarm in the air is refused by the vehicle, and the pilot is told why.
        ws.send(json.dumps({"type": "disarm"}))
        reply = json.loads(ws.recv(timeout=5))
        assert reply["cmd"] == "disarm" and reply["ok"] is False and reply["result"] == "DENIED"
        assert "in the air" in reply["text"]
        assert state(app).heartbeat.armed
        said = [m.text for m in state(app).messages.recent]
        assert "COMPONENT_ARM_DISARM: DENIED" in said and any("in the air" in t for t in said)
        # Bad input gets the error shape and the connection stays.
        ws.send("not json")
        assert json.loads(ws.recv(timeout=5))["error"] == "BadRequest"
        ws.send(json.dumps({"type": "sticks", "roll": 7}))
        assert json.loads(ws.recv(timeout=5))["error"] == "BadRequest"
        ws.send(json.dumps({"type": "mode", "mode": "ACRO"}))
        assert "ACRO" in json.loads(ws.recv(timeout=5))["error_msg"]
        # A second page has no sticks while the first has them: its sticks and its arm
        # are refused, its Land and its forced Disarm (emergencies) are carried out.
        with connect(ws_url + "/ws/control") as other:
            hello = json.loads(other.recv(timeout=5))
            assert hello["type"] == "hello" and hello["sticks"] is False
            other.send(json.dumps({"type": "sticks", "throttle": 1.0}))
            assert json.loads(other.recv(timeout=5))["error"] == "Conflict"
            other.send(json.dumps({"type": "mode", "mode": "ALTCTL"}))
            refused = json.loads(other.recv(timeout=5))
            assert refused["error"] == "Conflict" and "Disarm, Land and RTL" in refused["error_msg"]
            other.send(json.dumps({"type": "land"}))
            assert json.loads(other.recv(timeout=5))["ok"] is True
            assert wait_until(lambda: state(app).heartbeat.mode == "LAND", timeout=5)
            assert twin.pose().pos_enu_m[2] > 1.0  # still in the air
            other.send(json.dumps({"type": "disarm", "force": True}))
            reply = json.loads(other.recv(timeout=5))
            assert reply["cmd"] == "disarm" and reply["ok"] is True, reply
            assert wait_until(lambda: not state(app).heartbeat.armed, timeout=5)


def test_control_is_refused_without_a_vehicle(tmp_path) -> None:
    app = create_app(
        load_settings(
            None,
            {
                "link.source": "none",
                "viser.enabled": False,
                "recording.sessions_dir": str(tmp_path),
            },
            environ={},
        )
    )
    with run_uvicorn(app) as url, connect(url.replace("http", "ws") + "/ws/control") as ws:
        reply = json.loads(ws.recv(timeout=5))
        assert reply["error"] == "Conflict" and "No vehicle to command" in reply["error_msg"]


def test_browser_keyboard_flies_the_twin(tmp_path) -> None:
    from tests.helpers import arm_and_climb, chromium, sticks_on

    app = sim_app(**{"recording.sessions_dir": str(tmp_path)})
    with run_uvicorn(app) as url, chromium() as browser:
        twin = app.state.station.twin
        assert wait_until(lambda: state(app) and state(app).gps.fix_type == 3, timeout=10)
        page = browser.new_page()
        sticks_on(page, url)
        arm_and_climb(page, app.state.station)
        # Sticks are sampled on the page's 50 Hz tick: the release shows by the next one.
        page.wait_for_function("window.fpvDebug.control.sticks.throttle === 0.5", timeout=2000)
        sticks = page.evaluate("window.fpvDebug.control.sticks")
        assert sticks == {"roll": 0, "pitch": 0, "yaw": 0, "throttle": 0.5}
        page.keyboard.down("KeyW")  # forward: east
        x0 = twin.pose().pos_enu_m[0]
        assert wait_until(lambda: twin.pose().pos_enu_m[0] > x0 + 1.0, timeout=8)
        page.keyboard.up("KeyW")
        # Mapping edits persist in the browser.
        page.click("#ctl-pad summary")
        page.fill("input[data-f='roll'][data-k='index']", "5")
        page.dispatch_event("input[data-f='roll'][data-k='index']", "change")
        saved = page.evaluate("JSON.parse(localStorage.getItem('fpv.control.gamepad'))")
        assert saved["map"]["roll"]["index"] == 5


def test_serve_source_sim_cli_prints_url_and_shows_the_twin(tmp_path) -> None:
    """What `make run` does: the station on the twin, from the command line."""
    import subprocess
    import sys

    import httpx

    from tests.helpers import free_port

    port = free_port()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "fpv_station.server",
            "serve",
            "--source",
            "sim",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--no-3d",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=tmp_path,
        env={
            **__import__("os").environ,
            "PYTHONPATH": str(__import__("pathlib").Path(__file__).resolve().parents[1]),
            "XDG_CONFIG_HOME": str(tmp_path / "config"),
        },
    )
    try:
        # First start: a control token is made, kept only for this user, and put in the URL.
        token_file = tmp_path / "config" / "fpv-station" / "token"
        assert proc.stdout is not None
        assert str(token_file) in proc.stdout.readline()
        line = proc.stdout.readline()
        token = token_file.read_text().strip()
        # Not a terminal (a log, the journal): the URL without the token, and where it is.
        assert line.startswith(f"fpv-station: open http://127.0.0.1:{port}/ (add ?token=TOKEN")
        assert str(token_file) in line and token not in line and len(token) >= 32
        assert token_file.stat().st_mode & 0o077 == 0
        start = f"http://127.0.0.1:{port}/api/recording/start"
        assert httpx.post(start, timeout=5).status_code == 401

        def status():
            try:
                return httpx.get(f"http://127.0.0.1:{port}/api/status", timeout=2).json()
            except httpx.HTTPError:
                return None

        assert wait_until(
            lambda: (
                (s := status())
                and s.get("state", {}).get("heartbeat", {}).get("autopilot") == "px4"
            ),
            timeout=20,
        ), status()
        assert status()["source"] == "sim"
        page = httpx.get(f"http://127.0.0.1:{port}/", timeout=5).text
        assert "/control.js" in page and 'id="control-widget"' in page
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.mark.timeout(150)  # a loaded machine runs the 10x twin slower
@pytest.mark.timeout(300)
def test_reset_after_a_flight_keeps_telemetry_flowing(tmp_path) -> None:
    """Reset puts the twin back on the pad; its telemetry must go on at once. Reset must
    not rewind the sim clock: the twin would stay silent for as long as it had run, 10 s
    of wall time here (40 s of sim time at 4x, a pace a loaded machine keeps), twice the
    wait for telemetry below."""
    app = sim_app(**{"recording.sessions_dir": str(tmp_path), "twin.realtime_factor": 4.0})
    with run_uvicorn(app) as url:
        twin = app.state.station.twin
        assert wait_until(lambda: twin.sim.t_s > 40.0, timeout=240)  # a hang guard
        with connect(url.replace("http", "ws") + "/ws/control") as ws:
            json.loads(ws.recv(timeout=5))  # hello
            flown_s = twin.sim.t_s
            ws.send(json.dumps({"type": "reset"}))
            assert json.loads(ws.recv(timeout=5)) == {"type": "ack", "cmd": "reset", "ok": True}
        after = time.monotonic()
        assert wait_until(lambda: (state(app).attitude.t_mono or 0) > after + 0.5, timeout=5)
        assert wait_until(lambda: (state(app).heartbeat.t_mono or 0) > after, timeout=5)
        assert not state(app).link.link_lost
        assert twin.sim.t_s >= flown_s  # carried back, not rebooted: its clock ran on


def test_keyboard_arm_gesture_legend_select_and_release_on_blur(tmp_path) -> None:
    from tests.helpers import chromium

    app = sim_app(**{"recording.sessions_dir": str(tmp_path)})
    with run_uvicorn(app) as url, chromium() as browser:
        assert wait_until(lambda: state(app) and state(app).gps.fix_type == 3, timeout=10)
        page = browser.new_page()
        page.goto(url + "/")
        page.wait_for_selector("#control-widget:not([hidden])", timeout=15_000)
        page.keyboard.press("?")
        assert page.locator("#key-legend").is_visible()
        assert "arm" in page.locator("#key-legend").inner_text()
        page.keyboard.press("Escape")
        assert page.locator("#key-legend").is_hidden()
        page.click("#ctl-toggle")
        page.wait_for_function("window.fpvDebug.control.enabled === true", timeout=15_000)
        # The documented gesture, without Shift: full throttle down and full yaw right.
        page.keyboard.down("ArrowDown")
        page.keyboard.down("KeyE")
        # `sticks` is null until the first tick after the sticks are turned on.
        page.wait_for_function("window.fpvDebug.control.sticks?.yaw === 1", timeout=2000)
        assert page.evaluate("window.fpvDebug.control.sticks.throttle") == 0
        assert wait_until(lambda: state(app).heartbeat.armed, timeout=8)
        page.keyboard.up("KeyE")
        page.keyboard.up("ArrowDown")
        # A focused <select> does not take the arrow keys while the sticks fly.
        select = page.locator("#task-select")
        select.focus()
        before = select.input_value()
        page.keyboard.down("ArrowDown")
        page.wait_for_function("window.fpvDebug.control.sticks.throttle < 0.5", timeout=2000)
        page.keyboard.up("ArrowDown")
        assert select.input_value() == before
        # The window loses focus with a key held: the sticks are centred.
        select.evaluate("e => e.blur()")
        page.keyboard.down("KeyW")
        page.wait_for_function("window.fpvDebug.control.sticks.pitch > 0", timeout=2000)
        page.evaluate("window.dispatchEvent(new Event('blur'))")
        page.wait_for_function("window.fpvDebug.control.sticks.pitch === 0", timeout=2000)
