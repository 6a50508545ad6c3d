"""Old firmware: 2013 ArduCopter (MAVLink 1) put its GPS altitude in GLOBAL_POSITION_INT
`alt` (metres of wander) and its barometer's height in `relative_alt`. Measured by `alt`,
the pilot's altitude read -3.6 m on the ground after landing. Where the two disagree on
the ground before arming, the pilot's altitude is `relative_alt`'s, and the state (and so
every recorded row) says which one measured it. Shaped tlogs (tests/shaped_tlog) go
through the station's framer and tracker, and through a real replay into a session."""

from __future__ import annotations

import csv
import json

import httpx
import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.recording import layout
from fpv_station.companion.state_tracker import StateTracker
from fpv_station.core.mavlink.framing import MavFramer
from fpv_station.core.mavlink.tlog_records import TlogReader
from tests import shaped_tlog
from tests import synthetic as syn
from tests.replayed import replayed_station

ARDUPILOT = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
ARM_S, LAND_S, END_S = 20.0, 44.0, 55.0
HEIGHT_M = 3.0


def flight() -> syn.Flight:
    """On the ground 20 s, armed, a 3 m climb, 12 m along x, down by 44 s, disarmed 3 s
    after touching down."""
    t = np.arange(0.0, END_S, 0.02)
    tau = t - ARM_S
    z = np.clip(np.minimum(tau - 1.0, LAND_S - t), 0.0, HEIGHT_M)
    x = 1.0 * np.clip(tau - 6.0, 0.0, 12.0)
    armed = (t >= ARM_S) & (t < LAND_S + 3.0)
    return syn.Flight(t_s=t, xyz_m=np.stack([x, np.zeros_like(t), z], 1), armed=armed)


def gps_wander(t: np.ndarray) -> np.ndarray:
    """A GPS altitude's slow wander: 3.6 m lower after landing than at arming."""
    return 3.05 * np.sin(2 * np.pi * t / 50.0)


def replay_through_tracker(path):
    """The pilot's altitude and its source after each packet, and whether armed."""
    tracker, framer, rows = StateTracker(), MavFramer(), []
    for t, packet in TlogReader(path):
        for msg in framer.feed(packet):
            if tracker.update(msg, t):
                s = tracker.state
                rows.append((t, s.heartbeat.armed, s.altitude.relative_alt_m, s.altitude.source))
    return rows


def on_ground_after_landing(rows, t0):
    return [a for t, armed, a, _ in rows if t - t0 > LAND_S + 1.0 and a is not None]


def test_gps_altitude_in_alt_reads_the_barometers_height_instead(tmp_path):
    f = flight()
    log = shaped_tlog.vehicle_flight(f, ARDUPILOT, alt_error_m=gps_wander(f.t_s), mavlink1=True)
    rows = replay_through_tracker(log.write(tmp_path / "old.tlog"))
    after = on_ground_after_landing(rows, log.t0)
    assert after and max(abs(a) for a in after) < 0.3, (min(after), max(after))  # was -3.6
    flying = [a for t, armed, a, _ in rows if armed and a is not None]
    assert max(flying) == pytest.approx(HEIGHT_M, abs=0.2)
    assert {src for t, armed, _, src in rows if armed} == {"relative_alt"}


def test_an_autopilot_whose_alt_and_relative_alt_agree_keeps_alt(tmp_path):
    """The same flight where `alt` is the estimator's: measured by `alt`, as before."""
    log = shaped_tlog.vehicle_flight(flight(), ARDUPILOT)
    rows = replay_through_tracker(log.write(tmp_path / "new.tlog"))
    assert {src for t, armed, _, src in rows if armed} == {"alt"}
    after = on_ground_after_landing(rows, log.t0)
    assert max(abs(a) for a in after) < 0.1


@pytest.mark.timeout(120)
def test_the_session_records_which_altitude_measured_the_flight(tmp_path):
    f = flight()
    log = shaped_tlog.vehicle_flight(f, ARDUPILOT, alt_error_m=gps_wander(f.t_s), mavlink1=True)
    path = log.write(tmp_path / "old.tlog")
    with replayed_station(path, tmp_path / "sessions") as base:
        status = httpx.get(f"{base}/api/status").json()
        assert status["state"]["altitude"]["source"] == "relative_alt"
        (session,) = httpx.get(f"{base}/api/sessions").json()
    with open(tmp_path / "sessions" / session["id"] / layout.TELEMETRY_CSV) as fh:
        rows = [r for r in csv.DictReader(fh) if r["heartbeat.armed"] == "1"]
    assert {r["altitude.source"] for r in rows} == {"relative_alt"}
    meta = json.loads((tmp_path / "sessions" / session["id"] / layout.SESSION_JSON).read_text())
    assert meta["arming"]["altitude_source"] == "relative_alt"  # said once, for the flight
    heights = [float(r["altitude.relative_alt_m"]) for r in rows]
    assert max(heights) == pytest.approx(HEIGHT_M, abs=0.2)
    assert abs(heights[-1]) < 0.3  # on the ground at disarming, not -3.6 m


def test_a_home_set_on_the_ground_is_no_disagreement(tmp_path):
    """ArduPilot sets its home at the first GPS fix: `relative_alt` steps once (here by
    3 m, 10 s before arming) while `alt` holds. One step is the home moving, not two
    sensors wandering apart: the flight stays measured by `alt`."""
    log = shaped_tlog.vehicle_flight(flight(), ARDUPILOT)
    decoder = mavlink.MAVLink(None)
    for k, (t, packet) in enumerate(log.records):
        msg = decoder.decode(bytearray(packet))
        if msg.get_type() == "GLOBAL_POSITION_INT" and t - log.t0 < ARM_S - 10.0:
            msg.relative_alt += 3000  # relative to a home at power-on, 3 m lower
            sender = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
            sender.seq = msg.get_seq()
            log.records[k] = (t, bytes(msg.pack(sender)))
    rows = replay_through_tracker(log.write(tmp_path / "home.tlog"))
    assert {src for t, armed, _, src in rows if armed} == {"alt"}
    flying = [a for t, armed, a, _ in rows if armed and a is not None]
    assert max(flying) == pytest.approx(HEIGHT_M, abs=0.2)
