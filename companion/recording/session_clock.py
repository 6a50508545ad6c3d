"""Which clock names and stamps a session: the station's, or the vehicle's GPS time.

A Pi has no real-time clock and often no internet in the field. Until a time service
has set it, its clock resumes where it stopped, so a session could be named last week.
The vehicle's GPS knows UTC (SYSTEM_TIME), so the rule is:

- the station's clock is synchronised and agrees with the vehicle's GPS time within
  `max_disagree_s` (or the vehicle has no GPS time): the station's clock;
- the station's clock is not synchronised, or disagrees with the vehicle's GPS time by
  more than `max_disagree_s`: the vehicle's GPS time (a GPS receiver keeps UTC to well
  under a millisecond; a clock that disagrees with it by seconds is the wrong one);
- a replayed log: the log's own time (the clock its recorder had), as everything else.

Whichever is used, every wall time in the session's files (`start_wall`, the rows'
`wall_time`, the frames' `t_wall`) stays on the station's clock, so that they line up
with each other; `offset_s` turns any of them into the UTC used: `utc = wall + offset_s`.
The session's name and `start_utc`/`end_utc` are in that UTC.
"""

from __future__ import annotations

from fpv_station.companion.recording.meta import SessionClock
from fpv_station.companion.vehicle_state import VehicleUtc

DEFAULT_MAX_DISAGREE_S = 5.0  # a few seconds: more than any link delay, less than a mistake


def choose_session_clock(
    station_wall: float,
    station_mono: float,
    station_synced: bool | None,
    vehicle: VehicleUtc | None,
    *,
    replay: bool = False,
    max_disagree_s: float = DEFAULT_MAX_DISAGREE_S,
) -> SessionClock:
    """The clock for a session that started at `station_wall` (the station's time.time())
    and `station_mono` (its time.monotonic()), given the vehicle's GPS time as the state
    has it (`VehicleState.utc`; None or empty: it has none) and `station_synced`, the
    kernel's answer (None: unknown)."""
    vehicle_utc = None if vehicle is None else vehicle.at(station_mono)
    vehicle_source = vehicle.source if vehicle is not None and vehicle_utc is not None else None

    def clock(used: str, reason: str) -> SessionClock:
        offset = 0.0 if used != "vehicle" or vehicle_utc is None else vehicle_utc - station_wall
        return SessionClock(
            used=used,
            reason=reason,
            offset_s=round(offset, 3),
            station_synced=station_synced,
            station_start_wall=round(station_wall, 3),
            vehicle_start_utc=None if vehicle_utc is None else round(vehicle_utc, 3),
            vehicle_source=vehicle_source,
            max_disagree_s=max_disagree_s,
        )

    if replay:
        return clock("source", "a replayed log is stamped with its own recorded time")
    if vehicle_utc is None:
        if station_synced is False:
            return clock(
                "station",
                "the station's clock is not synchronised and the vehicle has no GPS time "
                "yet: the name and stamps may be wrong",
            )
        return clock("station", "the vehicle has no GPS time yet")
    off = vehicle_utc - station_wall
    if station_synced is False:
        return clock("vehicle", "the station's clock is not synchronised")
    if abs(off) > max_disagree_s:
        return clock("vehicle", f"the station's clock is {off:+.1f} s off the vehicle's GPS time")
    return clock("station", f"agrees with the vehicle's GPS time ({off:+.3f} s)")
