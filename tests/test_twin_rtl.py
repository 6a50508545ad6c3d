"""The twin's return to launch (MAV_CMD_NAV_RETURN_TO_LAUNCH, the pages' RTL button): from
a pymavlink ground station on a real UDP socket, refused on the ground, and in flight
flown home above the field's obstacles and landed there, its HEARTBEAT saying PX4's
AUTO.RTL from the command to the touchdown, the descent too (PX4's Return mode lands in
that mode)."""

from __future__ import annotations

import math

import numpy as np
from pymavlink import mavutil

from fpv_station.core.mavlink.px4_modes import PX4_MODES, px4_custom_mode
from tests.twin_gcs import REL, drain, latlon, take_off, wait_for

mav = mavutil.mavlink


def rtl(twin, gcs) -> int:
    drain(gcs, timeout=0.1)
    gcs.mav.command_long_send(1, 1, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0)
    acks = [a for a in wait_for(twin, gcs, "COMMAND_ACK", 3.0) if a.command == 20]
    assert acks, "no answer to RETURN_TO_LAUNCH"
    return acks[0].result


def fly_away(twin, gcs, east_m: float, north_m: float) -> None:
    """Take off to 2 m and go to a point of the field (DO_REPOSITION), 15 s of sim time."""

    def takeoff(g, home_amsl: float) -> None:
        g.mav.command_long_send(1, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 2.0)

    take_off(twin, gcs, takeoff)
    x, y = latlon(twin, east_m, north_m)
    gcs.mav.command_int_send(1, 1, REL, mav.MAV_CMD_DO_REPOSITION, 0, 0, -1, 1, 0, math.nan,
                             x, y, 2.0)  # fmt: skip
    twin.step_for(15.0)


def test_return_to_launch_flies_home_and_lands(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    assert rtl(twin, gcs) == mav.MAV_RESULT_DENIED  # on the ground
    fly_away(twin, gcs, -12.0, 5.0)
    home = twin.scene.start_xy_m
    assert np.hypot(*(twin.pose().pos_enu_m[:2] - home)) > 5.0  # away from home
    assert rtl(twin, gcs) == mav.MAV_RESULT_ACCEPTED
    top = 0.0
    # (custom_mode, distance from home, height) of each HEARTBEAT until the touchdown
    beats: list[tuple[int, float, float]] = []
    for _ in range(120):  # a hang guard: 60 s of sim time
        twin.step_for(0.5)
        pos = twin.pose().pos_enu_m
        top = max(top, pos[2])
        if twin.sim.commander.landed[0]:
            break
        for hb in drain(gcs, "HEARTBEAT", timeout=0.3):
            beats.append((hb.custom_mode, float(np.hypot(*(pos[:2] - home))), float(pos[2])))
    pos = twin.pose().pos_enu_m
    assert twin.sim.commander.landed[0], pos
    assert np.hypot(*(pos[:2] - home)) < 1.5, pos
    assert top > 2.7  # climbed from 2 m towards the return height (3 m) on the way
    rtl_mode = px4_custom_mode("RTL")
    assert beats and {mode for mode, _, _ in beats} == {rtl_mode}, beats
    assert any(d > 5.0 for _, d, _ in beats)  # on the way home
    assert any(d < 1.5 and z < 2.0 for _, d, z in beats), beats  # and in the descent there


def test_choosing_return_mode_starts_the_return(twin_and_gcs) -> None:
    """DO_SET_MODE AUTO.RTL, as QGroundControl's mode menu sends it, flies home as the
    command does; the pilot's POSCTL then ends the return where it is."""
    twin, gcs = twin_and_gcs
    fly_away(twin, gcs, -14.0, 0.0)
    drain(gcs, timeout=0.1)
    custom = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    main, sub = PX4_MODES["RTL"]
    gcs.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, custom, main, sub, 0, 0, 0, 0)
    acks = [a for a in wait_for(twin, gcs, "COMMAND_ACK", 3.0) if a.command == 176]
    assert acks and acks[0].result == mav.MAV_RESULT_ACCEPTED
    start = twin.pose().pos_enu_m.copy()
    home = twin.scene.start_xy_m
    twin.step_for(3.0)
    hb = wait_for(twin, gcs, "HEARTBEAT", 2.0)
    assert hb and hb[-1].custom_mode == px4_custom_mode("RTL")
    now = twin.pose().pos_enu_m
    assert np.hypot(*(now[:2] - home)) < np.hypot(*(start[:2] - home)) - 1.0  # homeward
    main, sub = PX4_MODES["POSCTL"]
    gcs.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, custom, main, sub, 0, 0, 0, 0)
    twin.step_for(4.0)
    drain(gcs, timeout=0.1)
    hb = wait_for(twin, gcs, "HEARTBEAT", 2.0)
    assert hb and hb[-1].custom_mode == px4_custom_mode("POSCTL")
    held = twin.pose().pos_enu_m.copy()
    twin.step_for(3.0)
    assert np.hypot(*(twin.pose().pos_enu_m[:2] - held[:2])) < 0.5  # holds, not homeward
