"""Time without a real-time clock: sessions take UTC from the vehicle's GPS when the
station's clock is unsynchronised or wrong."""

import datetime as dt
import json
import time
from dataclasses import dataclass

import httpx
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import SessionMeta, write_meta
from fpv_station.companion.recording.recovery import mark_interrupted
from fpv_station.companion.recording.session_clock import choose_session_clock
from fpv_station.companion.recording.store import SessionStore
from fpv_station.companion.state_tracker import StateTracker
from fpv_station.companion.system_clock import clock_synchronised
from fpv_station.companion.vehicle_state import VehicleUtc
from fpv_station.core.mavlink.framing import MavFramer
from fpv_station.server.app import create_app
from fpv_station.server.settings import load_settings
from tests.helpers import run_uvicorn, wait_until
from tests.mav_vehicle import MavVehicle

WEEK_S = 7 * 86400.0
NOW = 1_795_000_000.0  # 2026-11-18


def gps(unix_s: float | None) -> VehicleUtc:
    """The vehicle's GPS time as the state holds it, heard at station time 0."""
    return VehicleUtc(0.0, unix_s, "SYSTEM_TIME") if unix_s is not None else VehicleUtc()


@pytest.mark.parametrize(
    ("synced", "vehicle", "used", "offset"),
    [
        (True, NOW + 0.3, "station", 0.0),  # agrees: the synchronised station
        (True, None, "station", 0.0),  # no GPS time yet
        (False, None, "station", 0.0),  # nothing better, and said so
        (False, NOW + 0.3, "vehicle", 0.3),  # not synchronised: GPS, even when close
        (True, NOW + WEEK_S, "vehicle", WEEK_S),  # synchronised but a week off GPS
        (None, NOW - 40.0, "vehicle", -40.0),  # unknown, 40 s off GPS
        (None, NOW + 1.0, "station", 0.0),  # unknown, agrees
    ],
)
def test_the_rule(synced, vehicle, used, offset):
    c = choose_session_clock(NOW, 0.0, synced, gps(vehicle), max_disagree_s=5.0)
    assert c.used == used and c.offset_s == pytest.approx(offset)
    assert c.station_synced is synced and c.station_start_wall == NOW
    assert c.vehicle_start_utc == vehicle and c.reason
    assert c.vehicle_source == ("SYSTEM_TIME" if vehicle is not None else None)
    if synced is False and vehicle is None:
        assert "may be wrong" in c.reason


def test_the_vehicles_time_runs_on_with_the_monotonic_clock():
    """GPS time heard 2.5 s before the session started (station monotonic 10.0 -> 12.5)."""
    heard = VehicleUtc(10.0, NOW + WEEK_S, "SYSTEM_TIME")
    c = choose_session_clock(NOW, 12.5, True, heard)
    assert c.vehicle_start_utc == NOW + WEEK_S + 2.5 and c.offset_s == WEEK_S + 2.5


def test_a_replay_keeps_its_own_time():
    c = choose_session_clock(NOW, 0.0, None, gps(NOW + WEEK_S), replay=True)
    assert (c.used, c.offset_s) == ("source", 0.0)


def _packet(mav, msg) -> bytes:
    buf = msg.pack(mav)
    mav.seq = (mav.seq + 1) % 256
    return buf


def test_tracker_takes_utc_from_the_autopilot_only():
    tracker, framer = StateTracker(), MavFramer()
    ap = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    gcs = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)  # MAVProxy sets times too
    hb = ap.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 3)

    def feed(mav, msg, t):
        for m in framer.feed(_packet(mav, msg)):
            tracker.update(m, t)

    feed(ap, hb, 10.0)
    feed(ap, ap.system_time_encode(0, 5000), 10.5)  # autopilot clock not set yet
    assert tracker.state.utc.unix_s is None
    feed(ap, ap.gps_raw_int_encode(4_000_000, 3, 0, 0, 0, 80, 120, 0, 0, 10), 10.6)  # boot time
    assert tracker.state.utc.unix_s is None
    feed(gcs, gcs.system_time_encode(int((NOW + WEEK_S) * 1e6), 0), 11.0)
    assert tracker.state.utc.unix_s is None  # another ground station's clock: not the vehicle's
    # An autopilot that puts Unix time in GPS_RAW_INT: used while there is no SYSTEM_TIME.
    feed(ap, ap.gps_raw_int_encode(int(NOW * 1e6), 3, 0, 0, 0, 80, 120, 0, 0, 10), 12.0)
    assert tracker.state.utc.source == "GPS_RAW_INT" and tracker.state.utc.unix_s == NOW
    feed(ap, ap.system_time_encode(int((NOW + 1.25) * 1e6), 6000), 13.0)
    utc = tracker.state.utc
    assert utc.source == "SYSTEM_TIME" and utc.at(15.0) == pytest.approx(NOW + 3.25)
    feed(ap, ap.gps_raw_int_encode(int((NOW + 2) * 1e6), 3, 0, 0, 0, 80, 120, 0, 0, 10), 14.0)
    assert tracker.state.utc.source == "SYSTEM_TIME"  # SYSTEM_TIME stays the one


@dataclass
class Flight:
    """One armed-then-disarmed flight recorded by a real station over UDP."""

    health_clock: dict  # /api/health "clock" before arming: what the page shows
    station_start: float  # this machine's clock at arming
    meta: dict  # the session's session.json
    listed: dict  # its entry in GET /api/sessions


def fly_one_session(tmp_path, gps_utc_offset_s: float | None) -> Flight:
    root = tmp_path / "sessions"
    with MavVehicle("udp") as v:
        v.gps_utc_offset_s = gps_utc_offset_s
        settings = load_settings(
            environ={},
            overrides={
                "link.source": v.station_source,
                "viser.enabled": False,
                "recording.sessions_dir": str(root),
                "recording.post_disarm_tail_s": 0.2,
                "recording.min_free_mb": 0,
            },
        )
        with run_uvicorn(create_app(settings)) as base:
            status = lambda: httpx.get(f"{base}/api/recording").json()  # noqa: E731
            assert wait_until(lambda: v.sent["SYSTEM_TIME"] >= 2, timeout=10)
            time.sleep(0.3)
            health_clock = httpx.get(f"{base}/api/health").json()["clock"]
            station_start = time.time()
            v.arm()
            assert wait_until(lambda: status()["recording"], timeout=5)
            time.sleep(1.0)
            v.disarm()
            assert wait_until(lambda: not status()["recording"], timeout=5)
            sid = status()["last_stop"]["id"]
            listed = next(s for s in httpx.get(f"{base}/api/sessions").json() if s["id"] == sid)
    meta = json.loads((root / sid / layout.SESSION_JSON).read_text())
    return Flight(health_clock, station_start, meta, listed)


@pytest.mark.parametrize("offset_s", [-WEEK_S, 3 * 365 * 86400.0])
def test_a_session_is_named_by_the_vehicles_gps_time(tmp_path, offset_s):
    """A vehicle whose GPS time is a week behind (the station's clock ran on) or three years
    ahead of this machine's clock: the session is named and stamped in the GPS time, the
    rows keep the station's clock, and session.json says which, and by how much."""
    f = fly_one_session(tmp_path, offset_s)
    assert f.health_clock["sessions_use"] == "vehicle"
    assert f.health_clock["vehicle_offset_s"] == pytest.approx(offset_s, abs=0.5)
    assert f.health_clock["station_synced"] == clock_synchronised()
    meta, clock = f.meta, f.meta["clock"]
    assert clock["used"] == "vehicle" and clock["named_by"] == "vehicle"
    assert clock["vehicle_source"] == "SYSTEM_TIME"
    assert clock["offset_s"] == pytest.approx(offset_s, abs=0.5)
    assert clock["station_start_wall"] == pytest.approx(f.station_start, abs=2.0)
    assert meta["start_wall"] == pytest.approx(f.station_start, abs=2.0)  # the rows' clock
    gps_start = f.station_start + offset_s
    assert abs(layout.session_start_from_id(meta["id"]) - gps_start) < 3.0
    start_utc = dt.datetime.fromisoformat(meta["start_utc"]).timestamp()
    assert abs(start_utc - gps_start) < 3.0
    end_utc = dt.datetime.fromisoformat(meta["end_utc"]).timestamp()
    assert end_utc - start_utc == pytest.approx(meta["duration_s"], abs=0.01)
    assert f.listed["start_utc"] == meta["start_utc"]  # the list shows the stamp, not the wall


def test_a_vehicle_without_gps_time_leaves_the_station_clock(tmp_path):
    f = fly_one_session(tmp_path, None)  # SYSTEM_TIME says 0: no fix yet
    assert f.health_clock["sessions_use"] == "station"
    assert f.health_clock["vehicle_offset_s"] is None
    clock = f.meta["clock"]
    assert clock["used"] == "station" and clock["offset_s"] == 0.0
    assert clock["vehicle_start_utc"] is None and clock["station_synced"] == clock_synchronised()
    assert abs(layout.session_start_from_id(f.meta["id"]) - clock["station_start_wall"]) < 1.0


def test_an_interrupted_session_ends_in_its_own_clock(tmp_path):
    """kill -9 mid-flight: the next start's recovery stamps the end in the session's UTC."""
    clock = choose_session_clock(NOW, 0.0, False, gps(NOW - WEEK_S))
    sid = layout.session_id_for(NOW + clock.offset_s, "serial")
    folder = tmp_path / sid
    folder.mkdir()
    start_utc = layout.utc_label(NOW + clock.offset_s)
    meta = SessionMeta(id=sid, start_wall=NOW, start_utc=start_utc, clock=clock)
    write_meta(folder / layout.SESSION_JSON, meta)
    lines = ["t_s,wall_time", *(f"{i * 0.5},{NOW + i * 0.5}" for i in range(21)), "10.5,17"]
    (folder / layout.TELEMETRY_CSV).write_text("\n".join(lines))  # cut mid-row
    assert mark_interrupted(SessionStore(tmp_path)) == [sid]
    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    assert meta["status"] == "interrupted" and meta["duration_s"] == 10.0
    assert meta["end_utc"] == layout.utc_label(NOW - WEEK_S + 10.0)
    assert meta["start_utc"].startswith("2026-11-11")
