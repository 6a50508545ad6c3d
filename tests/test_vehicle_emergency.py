"""Disarm, Land and RTL for a real vehicle: a station on a live UDP link to a test
vehicle (real MAVLink bytes, answered with COMMAND_ACK as an autopilot does) sends each
to the followed autopilot from any page with the control token, shows the vehicle's
answer (accepted, denied with its reason, no answer), and sends nothing else: no sticks,
no arming, no mode. The pilot page shows the buttons and not the sticks."""

from __future__ import annotations

import json
import math

import httpx
import pytest
from playwright.sync_api import expect
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from fpv_station.server.app import create_app
from tests.helpers import chromium, run_uvicorn, station_settings, wait_until
from tests.mav_vehicle import MavVehicle

TOKEN = "s3cret"
SYSID, COMPID = 42, 1  # not 1/1: the commands must go to the ids heard on the link


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    with MavVehicle("udp", sysid=SYSID, compid=COMPID) as vehicle:
        vehicle.command_results = {
            mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: mavlink.MAV_RESULT_ACCEPTED,
            mavlink.MAV_CMD_COMPONENT_ARM_DISARM: mavlink.MAV_RESULT_ACCEPTED,
            mavlink.MAV_CMD_NAV_LAND: mavlink.MAV_RESULT_DENIED,
        }
        vehicle.command_texts = {mavlink.MAV_CMD_NAV_LAND: "Land denied: no position"}
        settings = station_settings(
            vehicle.station_source, tmp_path_factory.mktemp("sessions"), **{"server.token": TOKEN}
        )
        app = create_app(settings)
        with run_uvicorn(app) as base:
            link = app.state.station.link
            assert wait_until(lambda: link.autopilot() == (SYSID, COMPID), timeout=30)
            yield vehicle, base


def commands(vehicle: MavVehicle, command: int) -> list:
    return [
        m for m in list(vehicle.received) if m.get_type() == "COMMAND_LONG" and m.command == command
    ]


def sent_once_or_more(vehicle: MavVehicle, command: int):
    """The first of `command`'s COMMAND_LONGs; a loaded station may have sent it again
    before the answer came, each time with the next confirmation."""
    sent = commands(vehicle, command)
    assert [m.confirmation for m in sent] == list(range(len(sent))), sent
    return sent[0]


def control(base: str, token: str | None = TOKEN, origin: str | None = None):
    query = f"?token={token}" if token else ""
    headers = {"Origin": origin} if origin else None
    return connect(
        base.replace("http", "ws") + "/ws/control" + query,
        open_timeout=10,
        additional_headers=headers,
    )


def answer(ws) -> dict:
    """The next message that is not a hello."""
    while True:
        msg = json.loads(ws.recv(timeout=15))
        if msg.get("type") != "hello":
            return msg


@pytest.mark.timeout(120)
def test_emergency_commands_reach_the_vehicle_and_its_answer_comes_back(station):
    vehicle, base = station
    assert httpx.get(base + "/api/status", timeout=10).json()["control"] == "emergency"
    with control(base) as ws:
        hello = json.loads(ws.recv(timeout=10))
        assert hello["type"] == "hello" and hello["sticks"] is False
        assert hello["control"] == "emergency"

        ws.send(json.dumps({"type": "rtl"}))
        assert answer(ws) == {"type": "ack", "cmd": "rtl", "ok": True, "result": "ACCEPTED",
                              "text": "NAV_RETURN_TO_LAUNCH: ACCEPTED"}  # fmt: skip
        rtl = sent_once_or_more(vehicle, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)
        assert (rtl.target_system, rtl.target_component) == (SYSID, COMPID)
        assert (rtl.get_srcSystem(), rtl.get_srcComponent()) == (254, 190)  # the station

        ws.send(json.dumps({"type": "land"}))
        reply = answer(ws)
        assert (reply["cmd"], reply["ok"], reply["result"]) == ("land", False, "DENIED")
        assert reply["text"] == "Land denied: no position"  # the vehicle's own words
        land = sent_once_or_more(vehicle, mavlink.MAV_CMD_NAV_LAND)
        assert (land.target_system, land.target_component) == (SYSID, COMPID)
        assert math.isnan(land.param5) and math.isnan(land.param6)  # where it is

        # Disarm in flight: the page asked, and the force value goes with it.
        ws.send(json.dumps({"type": "disarm", "force": True}))
        assert answer(ws)["ok"] is True
        forced = sent_once_or_more(vehicle, mavlink.MAV_CMD_COMPONENT_ARM_DISARM)
        assert (forced.target_system, forced.target_component) == (SYSID, COMPID)
        assert (forced.param1, forced.param2) == (0.0, 21196.0)

        # A command lost on the way is sent again, its confirmation counted up, and the
        # vehicle's answer to the second comes back.
        before = len(commands(vehicle, mavlink.MAV_CMD_COMPONENT_ARM_DISARM))
        vehicle.commands_lost = 1
        ws.send(json.dumps({"type": "disarm"}))
        reply = answer(ws)
        assert (reply["ok"], reply["result"]) == (True, "ACCEPTED"), reply
        again = commands(vehicle, mavlink.MAV_CMD_COMPONENT_ARM_DISARM)[before:]
        assert [m.confirmation for m in again] == [0, 1], again

        # The first answer comes late, just before the answer to the second send, which
        # refuses (a vehicle busy with the first): the vehicle carried the disarm out.
        before = len(commands(vehicle, mavlink.MAV_CMD_COMPONENT_ARM_DISARM))
        vehicle.commands_held = 1
        vehicle.repeat_result = mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        ws.send(json.dumps({"type": "disarm"}))
        reply = answer(ws)
        assert (reply["ok"], reply["result"]) == (True, "ACCEPTED"), reply
        late = commands(vehicle, mavlink.MAV_CMD_COMPONENT_ARM_DISARM)[before:]
        assert [m.confirmation for m in late] == [0, 1], late
        vehicle.repeat_result = None

        # A vehicle that does not answer: sent three times, then said so.
        vehicle.command_results[mavlink.MAV_CMD_COMPONENT_ARM_DISARM] = None
        before = len(commands(vehicle, mavlink.MAV_CMD_COMPONENT_ARM_DISARM))
        ws.send(json.dumps({"type": "disarm"}))
        reply = answer(ws)
        assert (reply["ok"], reply["result"]) == (False, "NO_ANSWER"), reply
        assert "sent 3 times" in reply["text"], reply
        plain = commands(vehicle, mavlink.MAV_CMD_COMPONENT_ARM_DISARM)[before:]
        assert [m.confirmation for m in plain] == [0, 1, 2], plain
        assert all((m.param1, m.param2) == (0.0, 0.0) for m in plain)

        # Nothing else goes to a real vehicle: no sticks, no arming, no mode, no take-off.
        sent = len(vehicle.received_types())
        ws.send(json.dumps({"type": "sticks", "roll": 0, "pitch": 1, "yaw": 0, "throttle": 1}))
        refused = answer(ws)
        assert refused["error"] == "Conflict" and "radio" in refused["error_msg"], refused
        for cmd in ({"type": "arm"}, {"type": "mode", "mode": "POSCTL"}, {"type": "takeoff"}):
            ws.send(json.dumps(cmd))
            refused = answer(ws)
            assert refused["error"] == "Conflict", refused
            assert refused["error_msg"].startswith(cmd["type"] + ":"), refused
    later = vehicle.received_types()[sent:]
    assert "MANUAL_CONTROL" not in later and "COMMAND_LONG" not in later, later
    vehicle.command_results[mavlink.MAV_CMD_COMPONENT_ARM_DISARM] = mavlink.MAV_RESULT_ACCEPTED


def test_the_token_and_the_origin_guard_still_hold(station):
    vehicle, base = station
    before = len(commands(vehicle, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH))
    for token in (None, "wrong"):
        with control(base, token) as ws:
            refused = json.loads(ws.recv(timeout=10))
            assert refused["error"] == "Unauthorized", refused
            with pytest.raises(ConnectionClosed) as closed:
                ws.send(json.dumps({"type": "rtl"}))
                ws.recv(timeout=10)
            assert closed.value.rcvd.code == 4401
    with pytest.raises(InvalidStatus) as exc:  # another site's page, with the token
        control(base, origin="http://evil.example")
    assert exc.value.response.status_code == 403
    assert len(commands(vehicle, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)) == before


@pytest.mark.timeout(120)
def test_the_pilot_page_shows_the_buttons_and_sends_rtl(station):
    vehicle, base = station
    before = len(commands(vehicle, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH))
    with chromium() as browser:
        page = browser.new_page(viewport={"width": 1280, "height": 720})
        page.goto(f"{base}/?token={TOKEN}")
        buttons = page.locator("#toolbar .emergency")
        expect(buttons).to_be_visible(timeout=30_000)
        for kind in ("disarm", "land", "rtl"):
            expect(buttons.locator(f"[data-emergency={kind}]")).to_be_visible()
        expect(page.locator("#control-widget")).to_be_hidden()  # no sticks for a real one
        buttons.locator("[data-emergency=rtl]").click()
        expect(page.locator("#toast")).to_contain_text("rtl: done", timeout=20_000)
        buttons.locator("[data-emergency=land]").click()
        expect(page.locator("#toast")).to_contain_text("land refused (DENIED): Land denied")
    assert len(commands(vehicle, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH)) == before + 1
