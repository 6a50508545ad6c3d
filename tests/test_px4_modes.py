"""The code base's one PX4 mode table (core.mavlink.px4_modes) against PX4's numbers."""

import itertools

from pymavlink import mavutil

from fpv_station.core.mavlink.px4_modes import (
    PX4_MODES,
    px4_custom_mode,
    px4_main_sub,
    px4_mode_name,
)


def test_custom_modes_are_px4s():
    # px4_custom_mode.h: main << 16 | sub << 24
    assert px4_custom_mode("POSCTL") == 3 << 16
    assert px4_custom_mode("STABILIZED") == 7 << 16
    assert px4_custom_mode("MISSION") == (4 << 16) | (4 << 24)
    assert px4_main_sub(px4_custom_mode("LAND")) == (4, 6)
    assert PX4_MODES["TAKEOFF"] == (4, 2)


def test_names_agree_with_what_ground_stations_show():
    for main, sub in itertools.product(range(10), range(10)):
        custom = (main << 16) | (sub << 24)
        shown = mavutil.interpret_px4_mode(0, custom)
        assert (px4_mode_name(main, sub) or "UNKNOWN") == shown, (main, sub)
    assert px4_mode_name(2, 5) == "ALTCTL"  # a sub mode means nothing outside AUTO
    assert px4_mode_name(4, 0) is None
