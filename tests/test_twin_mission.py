"""The twin as a vehicle for real ground stations: the mission protocol (download, upload,
a lost request, refusals), an AUTO.MISSION flight, take-off heights as PX4's and
ArduPilot's ground stations send them, and DO_REPOSITION by COMMAND_INT. A pymavlink
ground station on a real UDP socket; the twin stepped faster than real time."""

from __future__ import annotations

import math
import socket
import time

import numpy as np
import pytest
from pymavlink import mavutil

from fpv_station.server.app import create_app
from tests.helpers import free_port, run_uvicorn, station_settings, wait_until
from tests.twin_flights import NO_CAMERAS
from tests.twin_gcs import MISSION, REL, download, drain, latlon, take_off, upload, wait_for

mav = mavutil.mavlink


def test_empty_mission_fence_and_rally_download_as_qgroundcontrol_asks(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    for mission_type in (mav.MAV_MISSION_TYPE_MISSION, mav.MAV_MISSION_TYPE_FENCE, 2):
        assert download(twin, gcs, mission_type) == []


def test_upload_with_a_lost_request_download_and_fly_the_mission(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    ack = upload(twin, gcs, MISSION, drop_request=2)
    assert ack.type == mav.MAV_MISSION_ACCEPTED
    items = download(twin, gcs)
    assert [(i.seq, i.command, i.frame) for i in items] == [
        (n, it[1], it[0]) for n, it in enumerate(MISSION)
    ]
    assert (items[1].x, items[1].y) == latlon(twin, -8.0, 0.0) and items[1].z == 4.0
    assert items[2].param1 == 2.0

    # QGroundControl's "start mission" on PX4: Mission mode, then arm.
    gcs.mav.set_mode_send(1, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, (4 << 16) | (4 << 24))
    gcs.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    reached, modes, track, max_alt = [], set(), [], 0.0
    for _ in range(240):  # up to 60 s of flight
        twin.step_for(0.25)
        for m in drain(gcs, timeout=0.01):
            if m.get_type() == "MISSION_ITEM_REACHED":
                reached.append(m.seq)
            elif m.get_type() == "HEARTBEAT":
                modes.add(((m.custom_mode >> 16) & 0xFF, (m.custom_mode >> 24) & 0xFF))
        pos = twin.pose().pos_enu_m
        track.append(pos.copy())
        max_alt = max(max_alt, pos[2])
        if reached[-1:] == [3] and not twin.sim.commander.armed[0]:
            break
    assert reached == [0, 1, 2, 3]
    assert (4, 4) in modes  # the heartbeat says AUTO.MISSION
    path = np.array(track)
    for east, north in ((-8.0, 0.0), (-8.0, 6.0)):
        assert np.min(np.hypot(path[:, 0] - east, path[:, 1] - north)) < 1.0
    assert max_alt == pytest.approx(4.0, abs=0.6)
    start = twin.scene.start_xy_m
    assert np.hypot(*(path[-1, :2] - start)) < 1.0 and path[-1, 2] < 0.1  # home, landed
    assert not twin.sim.commander.armed[0]  # PX4 disarms after landing


def test_refusals_unflyable_item_and_fence_and_no_mission_mode(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    local = [(mav.MAV_FRAME_LOCAL_NED, mav.MAV_CMD_NAV_WAYPOINT, 0, 0, None, None, 4.0)]
    assert upload(twin, gcs, local).type == mav.MAV_MISSION_UNSUPPORTED_FRAME
    spline = [(REL, mav.MAV_CMD_NAV_SPLINE_WAYPOINT, 0, 0, -8.0, 0.0, 4.0)]
    assert upload(twin, gcs, spline).type == mav.MAV_MISSION_UNSUPPORTED
    fence = [(REL, mav.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 10, 0, -8.0, 0.0, 0.0)]
    assert upload(twin, gcs, fence, mav.MAV_MISSION_TYPE_FENCE).type == mav.MAV_MISSION_UNSUPPORTED
    assert upload(twin, gcs, [], mav.MAV_MISSION_TYPE_FENCE).type == mav.MAV_MISSION_ACCEPTED
    assert download(twin, gcs) == []  # nothing half-uploaded was kept
    gcs.mav.command_long_send(1, 1, mav.MAV_CMD_MISSION_START, 0, 0, 0, 0, 0, 0, 0, 0)
    ack = wait_for(twin, gcs, "COMMAND_ACK")[0]
    assert ack.command == mav.MAV_CMD_MISSION_START and ack.result == mav.MAV_RESULT_DENIED


@pytest.mark.parametrize(
    "gcs_kind",
    ["qgc-px4-amsl", "ardupilot-gcs-relative", "command-int-relative", "command-int-amsl"],
)
def test_takeoff_height_as_either_family_of_ground_stations_sends_it(twin_and_gcs, gcs_kind):
    twin, gcs = twin_and_gcs
    cmd = mav.MAV_CMD_NAV_TAKEOFF

    def send(g, home_amsl: float) -> None:
        if gcs_kind == "qgc-px4-amsl":  # QGC on PX4: home altitude + height
            g.mav.command_long_send(1, 1, cmd, 0, -1, 0, 0, math.nan, math.nan, math.nan,
                                    home_amsl + 3.0)  # fmt: skip
        elif gcs_kind == "ardupilot-gcs-relative":  # MAVProxy "takeoff 3", Mission Planner
            g.mav.command_long_send(1, 1, cmd, 0, 0, 0, 0, 0, 0, 0, 3.0)
        elif gcs_kind == "command-int-relative":
            g.mav.command_int_send(1, 1, REL, cmd, 0, 0, 0, 0, 0, math.nan, 0, 0, 3.0)
        else:
            g.mav.command_int_send(1, 1, mav.MAV_FRAME_GLOBAL_INT, cmd, 0, 0, 0, 0, 0,
                                   math.nan, 0, 0, home_amsl + 3.0)  # fmt: skip

    assert take_off(twin, gcs, send) == pytest.approx(3.0, abs=0.1)


def test_do_reposition_by_command_int_flies_there_and_holds(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    x, y = latlon(twin, -12.0, 5.0)
    # On the ground: refused, as PX4 does not fly off to a reposition from the ground.
    gcs.mav.command_int_send(1, 1, REL, mav.MAV_CMD_DO_REPOSITION, 0, 0, -1, 1, 0, math.nan,
                             x, y, 5.0)  # fmt: skip
    ack = wait_for(twin, gcs, "COMMAND_ACK")[0]
    assert ack.command == mav.MAV_CMD_DO_REPOSITION and ack.result == mav.MAV_RESULT_DENIED

    def takeoff(g, home_amsl: float) -> None:
        g.mav.command_long_send(1, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 3.0)

    take_off(twin, gcs, takeoff)
    drain(gcs, timeout=0.1)
    gcs.mav.command_int_send(1, 1, REL, mav.MAV_CMD_DO_REPOSITION, 0, 0, -1, 1, 0, math.nan,
                             x, y, 5.0)  # fmt: skip
    ack = wait_for(twin, gcs, "COMMAND_ACK")[0]
    assert ack.result == mav.MAV_RESULT_ACCEPTED
    twin.step_for(15.0)
    pos = twin.pose().pos_enu_m
    assert np.hypot(pos[0] + 12.0, pos[1] - 5.0) < 0.5 and pos[2] == pytest.approx(5.0, abs=0.3)
    assert twin.sim.commander.mode_name() == "LOITER"


@pytest.mark.timeout(120)
def test_a_ground_station_on_the_stations_forward_uploads_and_flies_a_mission(tmp_path):
    """QGroundControl on `--forward` of a station on the twin: the mission protocol and
    the flight go through the station's link both ways."""
    port = free_port(socket.SOCK_DGRAM)
    gcs = mavutil.mavlink_connection(
        f"udpin:127.0.0.1:{port}", source_system=255, source_component=190
    )
    settings = station_settings(
        "sim",
        **{
            "link.forward": [f"udpout:127.0.0.1:{port}"],
            "twin.realtime_factor": 4.0,
            **NO_CAMERAS,
        },
    )
    app = create_app(settings)
    try:
        with run_uvicorn(app):
            station = app.state.station
            twin = station.twin
            hb = gcs.wait_heartbeat(timeout=15)
            assert hb is not None and hb.autopilot == mav.MAV_AUTOPILOT_PX4
            assert wait_until(lambda: twin.sim.sensors.has_fix(twin.sim.t_s), 15)
            assert upload(twin, gcs, MISSION).type == mav.MAV_MISSION_ACCEPTED
            assert [i.command for i in download(twin, gcs)] == [it[1] for it in MISSION]
            gcs.mav.command_long_send(1, 1, mav.MAV_CMD_MISSION_START, 0, 0, 0, 0, 0, 0, 0, 0)
            gcs.mav.command_long_send(
                1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
            )
            reached: list[int] = []
            modes, heights = set(), []  # what the station itself saw of the flight
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                for m in drain(gcs, "MISSION_ITEM_REACHED", timeout=0.2):
                    reached.append(m.seq)
                seen = station.state.get().value
                modes.add(seen.heartbeat.mode)
                heights.append(seen.altitude.relative_alt_m or 0.0)
                if reached[-1:] == [3] and not twin.sim.commander.armed[0]:
                    break
            assert reached == [0, 1, 2, 3]
            assert "MISSION" in modes and max(heights) == pytest.approx(4.0, abs=0.6)
    finally:
        gcs.close()
