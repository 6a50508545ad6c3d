"""The twin's return to launch (MAV_CMD_NAV_RETURN_TO_LAUNCH, the pages' RTL button): from
a pymavlink ground station on a real UDP socket, refused on the ground, and in flight
flown home above the field's obstacles and landed there."""

from __future__ import annotations

import math

import numpy as np
from pymavlink import mavutil

from tests.test_twin_mission import REL, latlon, take_off, wait_for
from tests.test_twin_vehicle import drain

mav = mavutil.mavlink


def rtl(twin, gcs) -> int:
    drain(gcs, timeout=0.1)
    gcs.mav.command_long_send(1, 1, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0)
    acks = [a for a in wait_for(twin, gcs, "COMMAND_ACK", 3.0) if a.command == 20]
    assert acks, "no answer to RETURN_TO_LAUNCH"
    return acks[0].result


def test_return_to_launch_flies_home_and_lands(twin_and_gcs) -> None:
    twin, gcs = twin_and_gcs
    assert rtl(twin, gcs) == mav.MAV_RESULT_DENIED  # on the ground

    def takeoff(g, home_amsl: float) -> None:
        g.mav.command_long_send(1, 1, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 2.0)

    take_off(twin, gcs, takeoff)
    x, y = latlon(twin, -12.0, 5.0)
    gcs.mav.command_int_send(1, 1, REL, mav.MAV_CMD_DO_REPOSITION, 0, 0, -1, 1, 0, math.nan,
                             x, y, 2.0)  # fmt: skip
    twin.step_for(15.0)
    home = twin.scene.start_xy_m
    assert np.hypot(*(twin.pose().pos_enu_m[:2] - home)) > 5.0  # away from home
    assert rtl(twin, gcs) == mav.MAV_RESULT_ACCEPTED
    top = 0.0
    for _ in range(60):  # a hang guard: 60 s of sim time
        twin.step_for(1.0)
        top = max(top, twin.pose().pos_enu_m[2])
        if twin.sim.commander.landed[0]:
            break
    pos = twin.pose().pos_enu_m
    assert twin.sim.commander.landed[0], pos
    assert np.hypot(*(pos[:2] - home)) < 1.5, pos
    assert top > 2.7  # climbed from 2 m towards the return height (3 m) on the way
