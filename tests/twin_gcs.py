"""A pymavlink ground station talking to the twin's MAVLink vehicle (conftest's
`twin_and_gcs`): reading what it sent, the mission protocol as QGroundControl speaks it,
and a take-off. The twin is stepped, or waited for when it runs in real time."""

from __future__ import annotations

import math
import time

import pymap3d
from pymavlink import mavutil

mav = mavutil.mavlink
REL = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


def latlon(twin, east_m: float, north_m: float) -> tuple[int, int]:
    """A point of the field (ENU about the scene's home) as MAVLink's degrees * 1e7."""
    h = twin.scene.home
    lat, lon, _ = pymap3d.enu2geodetic(east_m, north_m, 0.0, h.lat_deg, h.lon_deg, h.alt_m)
    return int(round(lat * 1e7)), int(round(lon * 1e7))


def advance(twin, seconds: float) -> None:
    """Let `seconds` of sim time pass: stepped, or waited for when the twin runs in real
    time (in a station)."""
    if twin.running:
        time.sleep(seconds / twin.realtime_factor)
    else:
        twin.step_for(seconds)


def wait_for(twin, gcs, kind: str, seconds: float = 1.0, step_s: float = 0.05) -> list:
    """Step the twin until the GCS got a `kind` (returns all of them so far)."""
    got: list = []
    for _ in range(int(seconds / step_s)):
        advance(twin, step_s)
        got += drain(gcs, kind, timeout=0.02)
        if got:
            return got
    return got


def upload(twin, gcs, items: list[tuple], mission_type: int = 0, drop_request: int | None = None):
    """QGroundControl's upload: MISSION_COUNT, then each MISSION_ITEM_INT the vehicle asks
    for. `drop_request`: ignore the vehicle's first request for that item (a lost packet).
    Returns the vehicle's MISSION_ACK."""
    gcs.mav.mission_count_send(1, 1, len(items), mission_type)
    ignored = False
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        advance(twin, 0.05)
        for m in drain(gcs, timeout=0.02):
            if m.get_type() == "MISSION_ACK":
                return m
            if m.get_type() != "MISSION_REQUEST_INT":
                continue
            if m.seq == drop_request and not ignored:
                ignored = True
                continue
            frame, cmd, p1, p2, east, north, alt = items[m.seq]
            x, y = latlon(twin, east, north) if east is not None else (0, 0)
            gcs.mav.mission_item_int_send(
                1, 1, m.seq, frame, cmd, 0, 1, p1, p2, 0, math.nan, x, y, alt, mission_type
            )
        time.sleep(0.01)
    raise AssertionError("no MISSION_ACK")


def download(twin, gcs, mission_type: int = 0) -> list:
    """QGroundControl's download: MISSION_REQUEST_LIST, each item, the ack; the items."""
    gcs.mav.mission_request_list_send(1, 1, mission_type)
    count = wait_for(twin, gcs, "MISSION_COUNT")[0]
    assert count.mission_type == mission_type
    items = []
    for seq in range(count.count):
        gcs.mav.mission_request_int_send(1, 1, seq, mission_type)
        items.append(wait_for(twin, gcs, "MISSION_ITEM_INT")[0])
    gcs.mav.mission_ack_send(1, 1, mav.MAV_MISSION_ACCEPTED, mission_type)
    return items


# Take off to 4 m, fly 12 m east and 6 m north at 4 m (2 s hold), then land back home.
MISSION = [
    (REL, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, None, None, 4.0),
    (REL, mav.MAV_CMD_NAV_WAYPOINT, 0, 0, -8.0, 0.0, 4.0),
    (REL, mav.MAV_CMD_NAV_WAYPOINT, 2.0, 0, -8.0, 6.0, 4.0),
    (mav.MAV_FRAME_MISSION, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, None, None, 0.0),
]


def drain(gcs, kind: str | None = None, timeout: float = 0.3) -> list:
    """What the GCS receives within `timeout` s (only `kind` messages, if given)."""
    out, deadline = [], time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = gcs.recv_match(blocking=True, timeout=0.05)
        if msg is not None and (kind is None or msg.get_type() == kind):
            out.append(msg)
    return out


def take_off(twin, gcs, send) -> float:
    """Arm, send the take-off `send(gcs, home_amsl_m)`, fly; the height reached (m)."""
    gcs.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    twin.step_for(0.5)
    home = drain(gcs, "HOME_POSITION", timeout=0.1) or wait_for(twin, gcs, "HOME_POSITION", 3)
    send(gcs, home[-1].altitude / 1000)
    twin.step_for(12.0)
    return float(twin.pose().pos_enu_m[2])
