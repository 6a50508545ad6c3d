"""`fpv-station sim` as a MAVLink vehicle: a pymavlink ground station on a real UDP socket
flies a scripted take-off, 4 m hover and landing with MANUAL_CONTROL, as a pilot would."""

from __future__ import annotations

import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from pymavlink import mavutil

from fpv_station.core.scene import load_scene
from fpv_station.twin.pilot import Leg, Observation, Pilot
from tests.helpers import free_port

SPEED = 2.0  # real-time factor: the flight takes ~25 s of sim time


@pytest.fixture()
def sim_gcs():
    port = free_port(socket.SOCK_DGRAM)
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "fpv_station.server",
            "sim",
            "--mavlink",
            f"udpout:127.0.0.1:{port}",
            "--speed",
            str(SPEED),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        yield gcs
    finally:
        proc.terminate()
        out, _ = proc.communicate(timeout=10)
        gcs.close()
        assert "talking MAVLink" in out


def test_scripted_takeoff_hover_land_over_udp(sim_gcs) -> None:
    gcs = sim_gcs
    hb = gcs.wait_heartbeat(timeout=10)
    assert hb is not None and hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_PX4
    assert hb.type == mavutil.mavlink.MAV_TYPE_QUADROTOR
    assert gcs.flightmode == "POSCTL" and not gcs.motors_armed()
    seen: dict[str, list] = {k: [] for k in ("mode", "armed", "fix", "rc3", "servo1", "rel_alt")}

    def pump(timeout: float = 0.02) -> None:
        deadline = time.monotonic() + timeout
        while True:
            msg = gcs.recv_match(blocking=True, timeout=max(deadline - time.monotonic(), 0))
            if msg is None:
                return
            kind = msg.get_type()
            if kind == "HEARTBEAT":
                seen["mode"].append(gcs.flightmode)
                seen["armed"].append(bool(gcs.motors_armed()))
            elif kind == "GPS_RAW_INT":
                seen["fix"].append(
                    (msg.fix_type, msg.lat / 1e7, msg.lon / 1e7, msg.satellites_visible)
                )
            elif kind == "RC_CHANNELS":
                seen["rc3"].append(msg.chan3_raw)
            elif kind == "SERVO_OUTPUT_RAW":
                seen["servo1"].append(msg.servo1_raw)
            elif kind == "GLOBAL_POSITION_INT":
                seen["rel_alt"].append(msg.relative_alt / 1000)

    # Wait for the GPS fix, then change modes both ways PX4 accepts.
    deadline = time.monotonic() + 10
    while not (seen["fix"] and seen["fix"][-1][0] == 3):
        pump(0.1)
        assert time.monotonic() < deadline, "no 3D fix"
    gcs.mav.set_mode_send(1, mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 2 << 16)  # ALTCTL
    while "ALTCTL" not in seen["mode"]:
        pump(0.1)
        assert time.monotonic() < deadline + 5, "SET_MODE to ALTCTL not reflected"
    gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_DO_SET_MODE, 0, 1, 3, 0, 0, 0, 0, 0)
    ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
    assert ack.command == mavutil.mavlink.MAV_CMD_DO_SET_MODE and ack.result == 0
    gcs.mav.command_long_send(
        1, 1, mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
    )
    ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
    assert ack.command == 400 and ack.result == 0

    start = load_scene().start_xy_m
    pilot = Pilot([Leg("climb", alt_m=4.0), Leg("hold", alt_m=4.0, seconds=4.0), Leg("land")])
    deadline = time.monotonic() + 60 / SPEED + 15
    while not pilot.done:
        assert time.monotonic() < deadline, f"pilot stuck: {pilot.log}"
        pump(0.02)
        lp, att = gcs.messages.get("LOCAL_POSITION_NED"), gcs.messages.get("ATTITUDE")
        if lp is None or att is None:
            continue
        obs = Observation(
            t_s=lp.time_boot_ms / 1000,
            pos_enu_m=np.array([start[0] + lp.y, start[1] + lp.x, -lp.z]),
            vel_enu_mps=np.array([lp.vy, lp.vx, -lp.vz]),
            yaw_enu_rad=np.pi / 2 - att.yaw,
            armed=bool(gcs.motors_armed()),
        )
        roll, pitch, yaw, thr = pilot.update(obs)
        gcs.mav.manual_control_send(
            1, int(pitch * 1000), int(roll * 1000), int(thr * 1000), int(yaw * 1000), 0
        )
    pump(0.5)

    assert {"ALTCTL", "POSCTL"} <= set(seen["mode"])
    assert True in seen["armed"] and seen["armed"][-1] is False  # armed, then auto-disarmed
    fix, lat, lon, sats = seen["fix"][-1]
    assert fix == 3 and sats >= 8
    assert lat == pytest.approx(43.0021, abs=1e-3) and lon == pytest.approx(-78.7875, abs=1e-3)
    assert max(seen["rc3"]) > 1600 and min(seen["rc3"]) < 1400  # climb and descent sticks
    assert 900 in seen["servo1"] and max(seen["servo1"]) > 1400  # disarmed, then spinning
    # The stick loop runs over a real socket on a shared machine: allow some overshoot.
    assert 3.6 < max(seen["rel_alt"]) < 5.0
    assert seen["rel_alt"][-1] == pytest.approx(0.0, abs=0.3)


def test_set_message_interval_and_bad_bytes(sim_gcs) -> None:
    gcs = sim_gcs
    assert gcs.wait_heartbeat(timeout=10) is not None
    # Garbage must be counted and ignored, not kill the vehicle.
    for twin_addr in gcs.clients:
        gcs.port.sendto(b"\xfd\xff\x00garbage" * 20, twin_addr)
    gcs.mav.command_long_send(
        1,
        1,
        mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
        0,
        mavutil.mavlink.MAVLINK_MSG_ID_ATTITUDE,
        200_000,
        0,
        0,
        0,
        0,
        0,
    )
    ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
    assert ack.result == 0
    time.sleep(0.3)
    while gcs.recv_match(blocking=False):
        pass
    stamps = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < 3.0:
        msg = gcs.recv_match(type="ATTITUDE", blocking=True, timeout=0.1)
        if msg is not None:
            stamps.append(msg.time_boot_ms / 1000)
    # Rate in the vehicle's own (sim) time: independent of how loaded this machine is.
    rate_hz = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    assert rate_hz == pytest.approx(5.0, rel=0.1)
    gcs.mav.command_long_send(1, 1, 31337, 0, 0, 0, 0, 0, 0, 0, 0)
    ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
    assert ack.command == 31337 and ack.result == mavutil.mavlink.MAV_RESULT_UNSUPPORTED
