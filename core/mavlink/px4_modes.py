"""PX4's flight modes on the wire: the one mode table of the code base.

PX4 reports and accepts its mode as a custom mode, `main << 16 | sub << 24`
(px4_custom_mode.h); the sub mode means something only under AUTO. The names and numbers
are pymavlink's (`mavutil.px4_map`, QGroundControl's words): 'POSCTL', 'ALTCTL', 'LOITER',
'MISSION' and so on; tests/test_px4_modes.py checks that they still agree. They are kept
here rather than read from `pymavlink.mavutil`, whose import costs 9 MB and 50 ms of
start-up (core/mavlink/ardupilot_modes.py says why). The link names the modes it
receives with it, the twin encodes and decodes its own with it, and the control route
sends the pilot's choice with it.
"""

from __future__ import annotations

AUTO_MAIN_MODE = 4  # PX4_CUSTOM_MAIN_MODE_AUTO

# name -> (main, sub)
PX4_MODES: dict[str, tuple[int, int]] = {
    "MANUAL": (1, 0),
    "STABILIZED": (7, 0),
    "ACRO": (5, 0),
    "RATTITUDE": (8, 0),
    "ALTCTL": (2, 0),
    "POSCTL": (3, 0),
    "LOITER": (AUTO_MAIN_MODE, 3),
    "MISSION": (AUTO_MAIN_MODE, 4),
    "RTL": (AUTO_MAIN_MODE, 5),
    "LAND": (AUTO_MAIN_MODE, 6),
    "RTGS": (AUTO_MAIN_MODE, 7),
    "FOLLOWME": (AUTO_MAIN_MODE, 8),
    "OFFBOARD": (6, 0),
    "TAKEOFF": (AUTO_MAIN_MODE, 2),
}
_BY_MAIN_SUB = {main_sub: name for name, main_sub in PX4_MODES.items()}


def px4_custom_mode(name: str) -> int:
    """The custom mode of a PX4 mode name (KeyError for a name PX4 lacks)."""
    main, sub = PX4_MODES[name]
    return (main << 16) | (sub << 24)


def px4_main_sub(custom_mode: int) -> tuple[int, int]:
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


def px4_mode_name(main: int, sub: int) -> str | None:
    """The name of a main/sub mode pair, None if PX4 has no such mode."""
    return _BY_MAIN_SUB.get((main, sub if main == AUTO_MAIN_MODE else 0))
