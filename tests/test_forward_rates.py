"""A ground station we forward to (MAVProxy on --forward) changes the autopilot's rates:
the station asks for its own again, says so in /api/status, and its session tlog holds
what that ground station sent to the vehicle, as QGroundControl's tlogs do."""

from __future__ import annotations

import socket
import time

import httpx
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.recording import layout
from fpv_station.server.app import create_app
from tests.helpers import free_port, run_uvicorn, station_settings, wait_until
from tests.mav_vehicle import MavVehicle


@pytest.mark.timeout(90)
def test_forwarded_gcs_cuts_attitude_rate_station_restores_it_and_records_it(tmp_path):
    mavproxy_port = free_port(socket.SOCK_DGRAM)
    mavproxy = mavutil.mavlink_connection(
        f"udpin:127.0.0.1:{mavproxy_port}", source_system=255, source_component=0
    )
    root = tmp_path / "sessions"
    with MavVehicle("udp") as v:
        settings = station_settings(
            v.station_source, root, **{"link.forward": [f"udpout:127.0.0.1:{mavproxy_port}"]}
        )
        with run_uvicorn(create_app(settings)) as base:
            status = lambda: httpx.get(f"{base}/api/status").json()["link"]  # noqa: E731
            assert wait_until(lambda: status()["stream_request"] == "message_interval", 15)
            assert v.rates_hz["ATTITUDE"] == pytest.approx(50.0)
            assert httpx.post(f"{base}/api/recording/start").status_code == 200
            # MAVProxy hears the vehicle through the forward, then asks for 2 Hz ATTITUDE.
            assert mavproxy.wait_heartbeat(timeout=10) is not None
            mavproxy.mav.heartbeat_send(
                mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
            )
            mavproxy.mav.command_long_send(
                1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                mavlink.MAVLINK_MSG_ID_ATTITUDE, 500_000, 0, 0, 0, 0, 0,
            )  # fmt: skip
            assert wait_until(lambda: status()["rate_changes_by_others"] == 1, 10)
            change = status()["last_rate_change"]
            assert (change["sysid"], change["compid"], change["via"]) == (255, 0, "forward")
            assert change["request"] == "SET_MESSAGE_INTERVAL ATTITUDE 2 Hz"
            # The vehicle heard MAVProxy's request, then ours again: ATTITUDE is back at 50 Hz.
            assert wait_until(lambda: status()["rates_reasserted"] == 1, 10)
            assert wait_until(lambda: v.rates_hz["ATTITUDE"] == pytest.approx(50.0), 5)
            asks = [
                (m.get_srcSystem(), m.param2)
                for m in list(v.received)
                if m.get_type() == "COMMAND_LONG"
                and int(m.param1) == mavlink.MAVLINK_MSG_ID_ATTITUDE
            ]
            assert asks[-2:] == [(255, 500_000), (254, 20_000)]
            time.sleep(2.5)  # a rate window after the change
            # 50 Hz asked, against MAVProxy's 2 Hz: far above 2 even on a starved box
            assert status()["rates_hz"]["ATTITUDE"] > 20
            assert status()["gcs_identity_clash"] is False
            session = httpx.post(f"{base}/api/recording/stop").json()["last_stop"]["id"]
    mavproxy.close()

    # The session's tlog holds the vehicle's packets, ours and MAVProxy's, read by pymavlink.
    log = mavutil.mavlink_connection(str(root / session / layout.MAVLINK_TLOG))
    senders: dict[tuple[int, int], set[str]] = {}
    while (m := log.recv_match()) is not None:
        senders.setdefault((m.get_srcSystem(), m.get_srcComponent()), set()).add(m.get_type())
    assert {"COMMAND_LONG", "HEARTBEAT"} <= senders[(255, 0)]  # MAVProxy, via the forward
    assert {"COMMAND_LONG", "HEARTBEAT"} <= senders[(254, 190)]  # the station itself
    assert "ATTITUDE" in senders[(1, 1)]
