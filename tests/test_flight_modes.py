"""The mode tables the station keeps (core.mavlink.px4_modes, core.mavlink.ardupilot_modes)
against pymavlink's own, and the names the link gives an ArduPilot HEARTBEAT."""

import itertools

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.state_tracker import mode_name
from fpv_station.core.mavlink.ardupilot_modes import BY_VEHICLE_TYPE, ardupilot_mode_name
from fpv_station.core.mavlink.px4_modes import AUTO_MAIN_MODE, PX4_MODES


def test_tables_are_pymavlinks():
    assert BY_VEHICLE_TYPE == mavutil.AP_MAV_TYPE_MODE_MAP_DEFAULT
    assert {n: (m, s) for n, (_b, m, s) in mavutil.px4_map.items()} == PX4_MODES
    assert AUTO_MAIN_MODE == mavutil.PX4_CUSTOM_MAIN_MODE_AUTO


class _Heartbeat:  # what mavutil.mode_string_v10 reads from a HEARTBEAT
    def __init__(self, autopilot: int, vehicle_type: int, base_mode: int, custom_mode: int):
        self.autopilot, self.type = autopilot, vehicle_type
        self.base_mode, self.custom_mode = base_mode, custom_mode

    def get_type(self) -> str:
        return "HEARTBEAT"


def test_ardupilot_names_are_what_ground_stations_show():
    custom = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    types = [*BY_VEHICLE_TYPE, mavlink.MAV_TYPE_GENERIC, 99]
    for vehicle_type, base, number in itertools.product(types, (custom, 0, 0x50), range(32)):
        ardupilot = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
        shown = mavutil.mode_string_v10(_Heartbeat(ardupilot, vehicle_type, base, number))
        assert mode_name(ardupilot, vehicle_type, base, number) == shown
    quad = mavlink.MAV_TYPE_QUADROTOR
    assert ardupilot_mode_name(quad, custom, 5) == "LOITER"
    assert ardupilot_mode_name(quad, custom, 12) == "Mode(12)"
    assert ardupilot_mode_name(quad, 0x50, 5) == "Mode(0x00000050)"
    assert ardupilot_mode_name(mavlink.MAV_TYPE_FIXED_WING, custom, 5) == "FBWA"
