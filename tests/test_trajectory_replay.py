"""Replay: GET /api/sessions/{id}/trajectory on real session folders (written in the
recorder's format by tests.synthetic, with real JPEG frames), through real uvicorn."""

from __future__ import annotations

import dataclasses
import math

import cv2
import httpx
import numpy as np
import pytest

from fpv_station.companion.recording import layout
from fpv_station.server.trajectory3d.replay import CameraFrames, build_trajectory, frames_at
from tests.stations import no_link_station
from tests.synthetic import (
    SESSION_A,
    SESSION_B,
    a_to_b_flight,
    write_session,
)


@pytest.fixture
def base(two_sessions_dir):
    panel = {"viser.enabled": True, "viser.port": 0}
    with no_link_station(two_sessions_dir, **panel) as (url, _):
        yield url


def test_frames_at_picks_the_newest_frame_at_or_before():
    cam = CameraFrames("front", np.array([0.0, 0.2, 0.4]), ["a", "b", "c"])
    assert frames_at(np.array([-1.0, 0.0, 0.1, 0.2, 5.0]), cam) == [None, "a", "a", "b", "c"]


def test_build_trajectory_origin_gaps_and_alignment():
    from fpv_station.core.geodesy import enu_to_geodetic

    t = np.arange(0.0, 10.0, 0.5)
    enu = np.column_stack([t, 2 * t, np.full(t.size, 3.0)])  # along a 63 deg bearing from east
    lat, lon, alt = enu_to_geodetic(enu, 43.0, -78.8, 180.0).T
    t[10:] += 5.0  # a 5 s silence
    armed = t >= 1.0
    r = build_trajectory("x", t, lat, lon, alt, armed=armed, gap_s=1.0)
    # armed first seen at i=2: the origin is the sample before, on the ground
    np.testing.assert_allclose([r.x_m[1], r.y_m[1], r.z_m[1]], [0, 0, 0], atol=1e-3)
    # ... stepped back to ground level when the pilot's altitude already shows a climb
    rel = np.where(t < 0.5, 0.0, 1.0)
    r0 = build_trajectory("x", t, lat, lon, alt, armed=armed, relative_alt_m=rel)
    np.testing.assert_allclose([r0.x_m[0], r0.y_m[0]], [0, 0], atol=1e-3)
    assert r.starts_run[0] and r.starts_run[10] and sum(r.starts_run) == 2
    a = build_trajectory("x", t, lat, lon, alt, armed=armed, align="end")
    np.testing.assert_allclose(a.y_m[-1], 0.0, atol=0.01)  # start-to-end on +x
    assert a.x_m[-1] == pytest.approx(math.hypot(r.x_m[-1], r.y_m[-1]), abs=0.01)
    assert a.align_rad == pytest.approx(-math.atan2(2, 1), abs=1e-3)
    # a flight that comes back: "farthest" still finds its axis, "end" would not
    back = np.concatenate([enu, enu[::-1]])
    blat, blon, balt = enu_to_geodetic(back, 43.0, -78.8, 180.0).T
    f = build_trajectory("x", np.arange(back.shape[0]) * 0.5, blat, blon, balt, align="farthest")
    i = int(np.argmax(np.hypot(f.x_m, f.y_m)))
    assert abs(f.y_m[i]) < 0.01 and f.x_m[i] > 20
    with pytest.raises(ValueError):
        build_trajectory("x", t[:0], lat[:0], lon[:0], alt[:0])


def test_trajectory_endpoint_matches_the_flown_path(base):
    r = httpx.get(f"{base}/api/sessions/{SESSION_A}/trajectory", timeout=10)
    assert r.status_code == 200, r.text
    j = r.json()
    flight = a_to_b_flight(heading_deg=30.0)
    # known truth: the flight's ENU about its arming point, at the reply's times
    enu_true = flight.enu_m() - flight.enu_m()[np.argmax(flight.armed)]
    t = np.asarray(j["t_s"])
    truth = np.column_stack([np.interp(t, flight.t_s, enu_true[:, k]) for k in range(3)])
    got = np.column_stack([j["x_m"], j["y_m"], j["z_m"]])
    assert np.abs(got - truth).max() < 0.15  # GPS sample-and-hold at 10 Hz, 1.2 m/s
    # the dropout (20-23 s) is a gap, and no jump is drawn across it
    gap_i = [i for i, s in enumerate(j["starts_run"]) if s]
    assert len(gap_i) == 2 and 22.9 <= t[gap_i[1]] <= 23.2
    # frames: the newest frame at or before each time, served by the recorder's route
    i = len(t) // 2
    front = j["frames"]["front"][i]
    assert front == layout.frame_relpath("front", int(math.floor(t[i] * 5.0 + 1e-9)))
    img = httpx.get(f"{base}/api/sessions/{SESSION_A}/files/{front}")
    assert img.status_code == 200 and img.content[:2] == b"\xff\xd8"
    decoded = cv2.imdecode(np.frombuffer(img.content, np.uint8), cv2.IMREAD_GRAYSCALE)
    seq = int(front.rsplit("/", 1)[1].split(".")[0])
    assert decoded.shape == (48, 64) and abs(int(decoded.mean()) - (seq * 7) % 255) <= 1
    # aligned as in the paper: start-to-end on +x, whatever the compass heading flown
    al = httpx.get(f"{base}/api/sessions/{SESSION_A}/trajectory?align=end").json()
    assert abs(al["y_m"][-1]) < 0.05 and al["x_m"][-1] > 35


def test_replay_and_analysis_share_the_flight_frame(base, two_sessions_dir):
    """The replay draws the frame the analysis measures in: same origin, same turn."""
    from fpv_station.analysis.flight_frame import align_track
    from fpv_station.analysis.track import load_track

    # A third flight whose arming is first seen in the air (HEARTBEAT at 1 Hz, a quick
    # pilot): the first armed sample is off the point where the vehicle was armed.
    f = a_to_b_flight(heading_deg=200.0)
    late = f.armed & (f.xyz_m[:, 2] > 0.8)
    late_id = "20261122T042000Z_serial"
    write_session(dataclasses.replace(f, armed=late), two_sessions_dir / late_id)
    for sid in (SESSION_A, SESSION_B, late_id):
        track = load_track(two_sessions_dir / sid)
        k = len(track) // 3  # any point off the origin sets +x
        lat, lon = float(track.lat_deg[k]), float(track.lon_deg[k])
        a = align_track(track, reference_latlon=(lat, lon))
        ref = f"{lat!r},{lon!r}"
        r = httpx.get(f"{base}/api/sessions/{sid}/trajectory", params={"reference": ref})
        assert r.status_code == 200, r.text
        j = r.json()
        o = j["origin"]
        assert (o["lat_deg"], o["lon_deg"], o["alt_m"]) == pytest.approx(a.origin, abs=1e-9)
        assert j["align_rad"] == pytest.approx(a.rotation_rad, abs=1e-9)
        got = np.column_stack([j["x_m"], j["y_m"], j["z_m"]])
        np.testing.assert_allclose(got, a.xyz_m, atol=2e-3)  # the reply is rounded to mm


def test_trajectory_endpoint_rejects_bad_ids(base):
    for bad, status in [
        ("..%2F..%2Fetc", 400),
        ("20991122T040000Z_sim", 404),
        ("not-a-session", 400),
    ]:
        r = httpx.get(f"{base}/api/sessions/{bad}/trajectory")
        assert r.status_code in (status, 404), (bad, r.status_code)
        assert "error" in r.json()
    r = httpx.get(f"{base}/api/sessions/{SESSION_A}/trajectory?reference=abc")
    assert r.status_code == 400 and r.json()["error"] == "BadRequest"
    r = httpx.get(f"{base}/api/sessions/{SESSION_A}/trajectory?align=sideways")
    assert r.status_code == 422
