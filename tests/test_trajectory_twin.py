"""A recorded twin flight, end to end: the station on the twin records task 2 (A to B),
the trajectory endpoint turns the recorded GPS into ENU about the arming point, and that
matches the twin's own LOCAL_POSITION_NED (recorded in the same rows) within GPS noise.
The live 3D panel drew the same flight meanwhile."""

from __future__ import annotations

import csv

import httpx
import numpy as np
import pytest

from fpv_station.companion.recording import layout
from tests.helpers import viser_viewer, wait_until
from tests.twin_flights import recorded_twin_flight


@pytest.mark.timeout(240)
def test_twin_session_trajectory_matches_local_position(tmp_path):
    overrides = {"viser.enabled": True, "viser.port": 0, "recording.rate_hz": 20.0}
    with recorded_twin_flight(tmp_path, 2, overrides) as flight:
        station, base, session_id = flight.station, flight.base_url, flight.session_id
        # The live panel kept the flight: the field of the twin's scene and a long trail,
        # drawn for its first viewer (nobody visited or watched during the flight).
        panel = station.trajectory3d
        assert panel.server is None and panel.trail.n_points > 100
        assert httpx.get(f"{base}/api/viser", timeout=30).json()["enabled"]  # the first visit
        assert {"pad:start", "pad:landing"} <= set(panel.scene.field_handles)
        assert panel.trail.n_points > 100
        with viser_viewer(panel.port):
            assert wait_until(lambda: len(panel.scene.chunk_handles) >= 2, timeout=10)
            live_end = np.asarray(panel.scene.vehicle.position)

        reply = httpx.get(f"{base}/api/sessions/{session_id}/trajectory", timeout=30)
        assert reply.status_code == 200, reply.text
        traj = reply.json()

    with open(tmp_path / session_id / layout.TELEMETRY_CSV, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["local_position.x_m"]]
    armed = np.array([r["heartbeat.armed"] == "1" for r in rows])
    assert armed.any()
    ned = np.array([[float(r[f"local_position.{k}_m"]) for k in "xyz"] for r in rows])
    enu_local = np.column_stack([ned[:, 1], ned[:, 0], -ned[:, 2]])
    enu_local -= enu_local[np.argmax(armed)]  # the same origin: where it armed
    # On the session clock, as the trajectory's fixes: each position message at the first
    # row that holds it.
    boot_ms = np.array([float(r["local_position.time_boot_ms"]) for r in rows])
    first = np.flatnonzero(np.r_[True, np.diff(boot_ms) != 0])
    t_rows = np.array([float(rows[i]["t_s"]) for i in first])
    enu_local = enu_local[first]

    t = np.asarray(traj["t_s"])
    got = np.column_stack([traj["x_m"], traj["y_m"], traj["z_m"]])
    want = np.column_stack([np.interp(t, t_rows, enu_local[:, k]) for k in range(3)])
    err = got - want
    horizontal = np.hypot(err[:, 0], err[:, 1])
    print(
        f"horizontal rms {np.sqrt(np.mean(horizontal**2)):.3f} m, vertical rms "
        f"{np.sqrt(np.mean(err[:, 2] ** 2)):.3f} m over {len(t)} fixes"
    )
    # GPS noise of the twin: 0.2 m horizontal drift, 0.4 m vertical drift, 0.05 m white,
    # plus up to one GPS period (5 Hz) of motion at cruise speed.
    assert np.sqrt(np.mean(horizontal**2)) < 1.0, horizontal.max()
    assert np.percentile(horizontal, 95) < 1.5
    assert np.sqrt(np.mean(err[:, 2] ** 2)) < 1.2
    # It really flew from the start pad to the landing pad, 40 m east.
    assert 35.0 < got[:, 0].max() < 45.0 and np.abs(got[:, 1]).max() < 3.0
    # The live panel ended where the recorded path ends (same origin, the arming point).
    assert np.linalg.norm(live_end[:2] - got[-1, :2]) < 1.5
    # Frames of the instant: the twin's rendered cameras were recorded with the flight.
    mid = len(t) // 2
    for cam in ("front", "bottom"):
        assert traj["frames"][cam][mid] is not None
