"""The twin's MAVLink vehicle in-process, stepped faster than real time, against a
pymavlink ground station on a real loopback UDP socket."""

from __future__ import annotations

import pytest
from pymavlink import mavutil

from tests.twin_gcs import drain


def test_rc_override_moves_the_sticks_and_shows_in_rc_channels(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    gcs.mav.rc_channels_override_send(1, 1, 1700, 1400, 1000, 2000, 0, 0, 0, 0)
    twin.step_for(0.2)
    roll, pitch, yaw, thr = twin.sim.sticks[0]
    assert (roll, pitch, yaw, thr) == pytest.approx((0.4, -0.2, 1.0, 0.0))
    rc = drain(gcs, "RC_CHANNELS")[-1]
    assert (rc.chan1_raw, rc.chan2_raw, rc.chan3_raw, rc.chan4_raw) == (1700, 1400, 1000, 2000)
    # Throttle down + yaw right held for a second: the arming gesture, through a radio
    # that keeps sending, as radios do.
    for _ in range(13):
        gcs.mav.rc_channels_override_send(1, 1, 1500, 1500, 1000, 2000, 0, 0, 0, 0)
        twin.step_for(0.1)
    assert twin.sim.commander.armed[0]
    # The radio goes silent: after 1 s the twin centres the sticks (hold).
    twin.step_for(1.5)
    assert tuple(twin.sim.sticks[0]) == (0.0, 0.0, 0.0, 0.5)


def test_interval_disable_request_message_and_version(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    gcs.mav.command_long_send(
        1,
        1,
        mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
        0,
        mavutil.mavlink.MAVLINK_MSG_ID_VFR_HUD,
        -1,
        0,
        0,
        0,
        0,
        0,
    )
    twin.step_for(0.1)
    drain(gcs, timeout=0.2)
    twin.step_for(2.0)
    kinds = {m.get_type() for m in drain(gcs)}
    assert "VFR_HUD" not in kinds and "ATTITUDE" in kinds
    gcs.mav.command_long_send(
        1,
        1,
        mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE,
        0,
        mavutil.mavlink.MAVLINK_MSG_ID_VFR_HUD,
        0,
        0,
        0,
        0,
        0,
        0,
    )
    gcs.mav.command_long_send(
        1,
        1,
        mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE,
        0,
        mavutil.mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
        0,
        0,
        0,
        0,
        0,
        0,
    )
    twin.step_for(0.1)
    got = drain(gcs)
    assert sum(m.get_type() == "VFR_HUD" for m in got) == 1  # once, not re-enabled
    version = [m for m in got if m.get_type() == "AUTOPILOT_VERSION"]
    assert version and version[0].flight_sw_version >> 24 == 1
    acks = [m for m in got if m.get_type() == "COMMAND_ACK"]
    assert [a.result for a in acks] == [0, 0]


def test_refused_arming_is_acked_denied_with_a_reason(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    twin.sim.state.crash[0] = 2  # as after hitting an obstacle
    gcs.mav.command_long_send(
        1, 1, mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0
    )
    twin.step_for(0.1)
    got = drain(gcs)
    ack = [m for m in got if m.get_type() == "COMMAND_ACK"][0]
    assert ack.result == mavutil.mavlink.MAV_RESULT_DENIED
    texts = [m.text for m in got if m.get_type() == "STATUSTEXT"]
    assert any("crashed" in t for t in texts)
    twin.step_for(1.0)
    hb = drain(gcs, "HEARTBEAT")[-1]
    assert hb.system_status == mavutil.mavlink.MAV_STATE_EMERGENCY


def test_true_geodetic_matches_the_gps_without_noise(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    twin.step_for(0.5)
    lat, lon, alt = twin.true_geodetic()
    gps = drain(gcs, "GPS_RAW_INT")[-1]
    assert gps.lat / 1e7 == pytest.approx(lat, abs=2e-7)
    assert gps.lon / 1e7 == pytest.approx(lon, abs=2e-7)
    assert alt == pytest.approx(twin.scene.home.alt_m, abs=0.01)  # on the start pad


def test_parameters_load_like_px4_and_are_read_only(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    gcs.mav.param_request_list_send(1, 1)
    twin.step_for(0.1)
    values = {m.param_id: m for m in drain(gcs, "PARAM_VALUE")}
    count = next(iter(values.values())).param_count
    assert len(values) == count and sorted(m.param_index for m in values.values()) == list(
        range(count)
    )
    assert values["MPC_XY_VEL_MAX"].param_value == pytest.approx(5.0)
    assert values["BAT1_N_CELLS"].param_value == 3
    gcs.mav.param_request_read_send(1, 1, b"MIS_TAKEOFF_ALT", -1)
    gcs.mav.param_set_send(1, 1, b"MPC_XY_VEL_MAX", 12.0, mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
    twin.step_for(0.1)
    got = drain(gcs)
    replies = {m.param_id: m.param_value for m in got if m.get_type() == "PARAM_VALUE"}
    assert replies == {"MIS_TAKEOFF_ALT": pytest.approx(2.5), "MPC_XY_VEL_MAX": pytest.approx(5.0)}
    assert any("read-only" in m.text for m in got if m.get_type() == "STATUSTEXT")
    assert twin.sim.config.gains.max_vel_xy_mps == 5.0


def test_home_position_is_where_it_armed(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    twin.sim.arm()
    got = []
    for _ in range(25):  # small steps: a burst of seconds would overflow the UDP buffer
        twin.step_for(0.1)
        got += drain(gcs, timeout=0.02)
    home = [m for m in got if m.get_type() == "HOME_POSITION"][-1]
    lat, lon, alt = twin.true_geodetic()
    assert home.latitude / 1e7 == pytest.approx(lat, abs=2e-7)
    assert home.longitude / 1e7 == pytest.approx(lon, abs=2e-7)
    assert home.altitude / 1000 == pytest.approx(alt, abs=0.05)


def test_telemetry_goes_on_when_the_sim_clock_goes_back(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    twin.step_for(20.0)
    drain(gcs, timeout=0.5)
    with twin.lock:
        twin.sim.reset()  # a rebooted vehicle: its clock starts again at 0
    twin.step_for(1.5)
    assert len(drain(gcs, "HEARTBEAT")) >= 1
    twin.step_for(1.0)
    assert len(drain(gcs, "ATTITUDE")) >= 10
