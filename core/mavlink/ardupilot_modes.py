"""ArduPilot's flight modes on the wire: the custom mode number per vehicle type, named as
ground stations show them ('STABILIZE', 'ALT_HOLD', 'LOITER', 'FBWA').

The names and numbers are pymavlink's (`mavutil.mode_mapping_*` and
`AP_MAV_TYPE_MODE_MAP_DEFAULT`, MAVProxy's words); tests/test_flight_modes.py checks that
they still agree. They are kept here rather than read from `pymavlink.mavutil`: importing
mavutil imports pymavlink's MAVLink 1 `all` dialect as well, 9 MB of memory and 50 ms
of start-up for tables the station otherwise never uses (docs/PERFORMANCE.md).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

# fmt: off
COPTER: dict[int, str] = {
    0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 5: "LOITER", 6: "RTL",
    7: "CIRCLE", 8: "POSITION", 9: "LAND", 10: "OF_LOITER", 11: "DRIFT", 13: "SPORT",
    14: "FLIP", 15: "AUTOTUNE", 16: "POSHOLD", 17: "BRAKE", 18: "THROW", 19: "AVOID_ADSB",
    20: "GUIDED_NOGPS", 21: "SMART_RTL", 22: "FLOWHOLD", 23: "FOLLOW", 24: "ZIGZAG",
    25: "SYSTEMID", 26: "AUTOROTATE", 27: "AUTO_RTL", 28: "TURTLE", 29: "RATE_ACRO",
}
PLANE: dict[int, str] = {
    0: "MANUAL", 1: "CIRCLE", 2: "STABILIZE", 3: "TRAINING", 4: "ACRO", 5: "FBWA", 6: "FBWB",
    7: "CRUISE", 8: "AUTOTUNE", 10: "AUTO", 11: "RTL", 12: "LOITER", 13: "TAKEOFF",
    14: "AVOID_ADSB", 15: "GUIDED", 16: "INITIALISING", 17: "QSTABILIZE", 18: "QHOVER",
    19: "QLOITER", 20: "QLAND", 21: "QRTL", 22: "QAUTOTUNE", 23: "QACRO", 24: "THERMAL",
    25: "LOITERALTQLAND", 26: "AUTOLAND",
}
ROVER: dict[int, str] = {
    0: "MANUAL", 1: "ACRO", 2: "LEARNING", 3: "STEERING", 4: "HOLD", 5: "LOITER", 6: "FOLLOW",
    7: "SIMPLE", 8: "DOCK", 9: "CIRCLE", 10: "AUTO", 11: "RTL", 12: "SMART_RTL", 15: "GUIDED",
    16: "INITIALISING",
}
TRACKER: dict[int, str] = {
    0: "MANUAL", 1: "STOP", 2: "SCAN", 4: "GUIDED", 10: "AUTO", 16: "INITIALISING",
}
SUB: dict[int, str] = {
    0: "STABILIZE", 1: "ACRO", 2: "ALT_HOLD", 3: "AUTO", 4: "GUIDED", 7: "CIRCLE",
    9: "SURFACE", 16: "POSHOLD", 19: "MANUAL",
}
BLIMP: dict[int, str] = {
    0: "LAND", 1: "MANUAL", 2: "VELOCITY", 3: "LOITER", 4: "RTL", 5: "AUTO", 6: "HOLD",
}
# fmt: on

# MAV_TYPE -> that firmware's table
BY_VEHICLE_TYPE: dict[int, dict[int, str]] = {
    **dict.fromkeys(
        (
            mavlink.MAV_TYPE_HELICOPTER,
            mavlink.MAV_TYPE_TRICOPTER,
            mavlink.MAV_TYPE_QUADROTOR,
            mavlink.MAV_TYPE_HEXAROTOR,
            mavlink.MAV_TYPE_OCTOROTOR,
            mavlink.MAV_TYPE_DECAROTOR,
            mavlink.MAV_TYPE_DODECAROTOR,
            mavlink.MAV_TYPE_COAXIAL,
        ),
        COPTER,
    ),
    **dict.fromkeys(
        (
            mavlink.MAV_TYPE_FIXED_WING,
            mavlink.MAV_TYPE_VTOL_TILTROTOR,
            mavlink.MAV_TYPE_VTOL_DUOROTOR,
            mavlink.MAV_TYPE_VTOL_QUADROTOR,
        ),
        PLANE,
    ),
    mavlink.MAV_TYPE_GROUND_ROVER: ROVER,
    mavlink.MAV_TYPE_SURFACE_BOAT: ROVER,
    mavlink.MAV_TYPE_ANTENNA_TRACKER: TRACKER,
    mavlink.MAV_TYPE_SUBMARINE: SUB,
    mavlink.MAV_TYPE_AIRSHIP: BLIMP,
}


def ardupilot_mode_name(vehicle_type: int, base_mode: int, custom_mode: int) -> str:
    """The mode of an ArduPilot HEARTBEAT, as `mavutil.mode_string_v10` says it
    ('Mode(0x...)' without a custom mode, 'Mode(N)' for a number the table lacks)."""
    if not base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return f"Mode(0x{base_mode:08x})"
    name = BY_VEHICLE_TYPE.get(vehicle_type, {}).get(custom_mode)
    return name if name is not None else f"Mode({custom_mode})"
