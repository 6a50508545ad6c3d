"""ArduPilot's EKF origin: GLOBAL_POSITION_INT says altitudes near 0 until "EKF3 IMU0
Origin set to GPS", then jumps to the true AMSL altitude (180 m here). The pilot's
altitude (since arming) must not jump with it: a 1.3 m hop reads 1.3 m, not 181 m.

Shaped tlogs (tests/shaped_tlog.vehicle_flight) go through the station's own framer and
state tracker packet by packet (every value the pilot could have seen), and through the
real `replay:` source into a real server, whose session and /api/status are read."""

from __future__ import annotations

import csv
import json

import httpx
import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.analysis.flights import split_flights
from fpv_station.companion.recording import layout
from fpv_station.server.app import create_app
from tests import shaped_tlog
from tests import synthetic as syn
from tests.helpers import run_uvicorn, station_settings, wait_until
from tests.known_flights import ARDUPILOT, EKF_CASES, EKF_HOP_M, ekf_hop
from tests.replayed import pilot_altitudes, replayed_station


@pytest.mark.parametrize("case", EKF_CASES)
def test_pilot_altitude_survives_the_ekf_origin_jump(case, tmp_path):
    flight, origin_s = EKF_CASES[case]
    path = shaped_tlog.vehicle_flight(flight, ARDUPILOT, origin_set_s=origin_s).write(
        tmp_path / "ekf.tlog"
    )
    alts, refs = pilot_altitudes(path)
    assert alts.max() <= EKF_HOP_M + 0.5, alts.max()  # before the fix: 181.3 m
    assert alts.max() >= EKF_HOP_M - 0.2  # and the hop is still seen
    assert "arming_retaken" in refs


def test_altitude_jump_without_a_message_is_a_frame_change_too(tmp_path):
    """An old ArduPilot log without the STATUSTEXT (or with it lost): the jump alone."""
    log = shaped_tlog.vehicle_flight(
        EKF_CASES["origin set during a low hop"][0], ARDUPILOT, origin_set_s=12.0
    )
    log.records = [(t, p) for t, p in log.records if b"Origin set" not in p]
    alts, refs = pilot_altitudes(log.write(tmp_path / "ekf.tlog"))
    assert alts.max() <= EKF_HOP_M + 0.5
    assert "arming_retaken" in refs


def test_fused_altitude_converging_slowly_to_gps_retakes_the_reference(tmp_path):
    """No step and no message: the fused altitude slides from near 0 to AMSL over 8 s on
    the ground (36 m a second is no jump). When it comes within 40 m of GPS, the frame
    change is the change of their offset; the hop after it reads as a hop."""
    flight = ekf_hop(take_off_s=20.0, land_s=26.0, end_s=34.0)
    log = shaped_tlog.vehicle_flight(flight, ARDUPILOT, origin_set_s=None)
    decoder = mavlink.MAVLink(None)
    ramp = (8.0, 16.0)
    for k, (t, packet) in enumerate(log.records):
        msg = decoder.decode(bytearray(packet))
        if msg.get_type() == "GLOBAL_POSITION_INT":
            s = float(np.clip((t - log.t0 - ramp[0]) / (ramp[1] - ramp[0]), 0.0, 1.0))
            msg.alt = int(msg.alt - (1.0 - s) * 179_700)  # from up + 0.3 m to AMSL
            sender = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
            sender.seq = msg.get_seq()
            log.records[k] = (t, bytes(msg.pack(sender)))
    alts, refs = pilot_altitudes(log.write(tmp_path / "slow.tlog"))
    assert "arming_retaken" in refs or "first_fix_retaken" in refs
    late = alts[-800:]  # the last ~11 s armed (~70 updates/s): the hop, after the slide
    assert late.max() == pytest.approx(EKF_HOP_M, abs=0.5)


@pytest.mark.timeout(120)
def test_replayed_session_records_the_hop_not_the_jump(tmp_path):
    flight, origin_s = EKF_CASES["origin set during a low hop"]
    path = shaped_tlog.vehicle_flight(flight, ARDUPILOT, origin_set_s=origin_s).write(
        tmp_path / "ekf.tlog"
    )
    settings = station_settings(f"replay:{path}?speed=5", tmp_path / "sessions")
    with run_uvicorn(create_app(settings)) as base:
        assert httpx.post(f"{base}/api/recording/start").status_code == 200
        status = lambda: httpx.get(f"{base}/api/status").json()  # noqa: E731
        assert wait_until(lambda: status()["link"]["replay_done"], timeout=60)
        altitude = status()["state"]["altitude"]
        session = httpx.post(f"{base}/api/recording/stop").json()["last_stop"]["id"]
    assert altitude["reference"] == "arming_retaken"
    assert altitude["retaken_because"] == "EKF origin set"
    folder = tmp_path / "sessions" / session
    with open(folder / layout.TELEMETRY_CSV) as f:
        rows = [r for r in csv.DictReader(f) if r["heartbeat.armed"] == "1"]
    recorded = max(float(r["altitude.relative_alt_m"]) for r in rows)
    assert EKF_HOP_M - 0.3 <= recorded <= EKF_HOP_M + 0.5
    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    assert meta["arming"]["reference_alt_m"] == pytest.approx(180.0, abs=0.5)


# A real ArduCopter log's first sortie: a 1.26 m hop, positions at 1 Hz over the radio,
# the height re-zeroed at arming (0.45 m of drift on the ground before), and the EKF
# origin set while it climbs, so that the frame's step and a climb of most of a metre
# fall between two positions. `relative_alt` is continuous across the origin.
HOP_1HZ_M = 1.26
REZERO_M = 0.45


def fast_hop() -> syn.Flight:
    """Armed at 5 s, a 0.8 m/s climb from 10 s to HOP_1HZ_M, 3 s up, down, disarmed."""
    t = np.arange(0.0, 30.0, 0.02)
    up = np.clip(np.minimum(0.8 * (t - 10.0), 0.8 * (16.0 - t)), 0.0, HOP_1HZ_M)
    xyz = np.stack([np.zeros_like(t), np.zeros_like(t), up], 1)
    return syn.Flight(t_s=t, xyz_m=xyz, armed=(t >= 5.0) & (t < 20.0))


def test_a_hop_whose_climb_falls_in_the_frames_step_is_still_a_hop(tmp_path):
    """The step between two positions is the frame's shift plus the climb; the shift is
    the step of `alt` less the step of `relative_alt`. And the zero is the altitude at
    arming after the re-zero: the autopilot's home, set there (`alt - relative_alt`),
    not the drifted height one heartbeat earlier. Taking the whole step as the shift and
    the drifted height as the zero read 0.01 m, and the analysis said "never flew"."""
    log = shaped_tlog.vehicle_flight(
        fast_hop(), ARDUPILOT, origin_set_s=10.5, position_hz=1, rezero_m=REZERO_M
    )
    path = log.write(tmp_path / "hop.tlog")
    alts, refs = pilot_altitudes(path)
    assert "arming_retaken" in refs
    assert alts.max() == pytest.approx(HOP_1HZ_M, abs=0.1)


@pytest.mark.timeout(120)
def test_the_missed_hops_session_holds_a_flight(tmp_path):
    """Replayed into a real station recording on arming: the session's pilot altitude
    holds one flight of the hop's height, and the analysis finds it (the hop is too low
    for a hover trial, which it says, but not that the vehicle never flew)."""
    log = shaped_tlog.vehicle_flight(
        fast_hop(), ARDUPILOT, origin_set_s=10.5, position_hz=1, rezero_m=REZERO_M
    )
    path = log.write(tmp_path / "hop.tlog")
    with replayed_station(path, tmp_path / "sessions") as base:
        (session,) = httpx.get(f"{base}/api/sessions").json()
        reply = httpx.get(f"{base}/api/sessions/{session['id']}/analysis?task=hover", timeout=30)
    assert "never flew" not in reply.text  # before: "the vehicle never flew"
    with open(tmp_path / "sessions" / session["id"] / layout.TELEMETRY_CSV) as f:
        rows = list(csv.DictReader(f))
    height = np.array([float(r["altitude.relative_alt_m"] or "nan") for r in rows])
    armed = np.array([r["heartbeat.armed"] == "1" for r in rows])
    t = np.array([float(r["t_s"]) for r in rows])
    (flight,) = split_flights(t, armed, height)
    assert np.nanmax(height[armed]) == pytest.approx(HOP_1HZ_M, abs=0.1)
    assert flight.airborne_s == pytest.approx(HOP_1HZ_M / 0.8 * 2 + 3 - 2 * 0.5 / 0.8, abs=1.1)
