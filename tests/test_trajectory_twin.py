"""A recorded twin flight, end to end: the station on the twin records task 2 (A to B),
the trajectory endpoint turns the recorded GPS into ENU about the arming point, and that
matches the twin's own LOCAL_POSITION_NED (recorded in the same rows) within GPS noise.
The live 3D panel drew the same flight meanwhile."""

from __future__ import annotations

import csv

import httpx
import numpy as np
import pytest

from companion.recording import layout
from server.app import create_app
from server.settings import load_settings
from tests.helpers import run_uvicorn, wait_until
from twin.pilot import Leg, Pilot, fly_twin, task_plan


@pytest.mark.timeout(240)
def test_twin_session_trajectory_matches_local_position(tmp_path):
    settings = load_settings(None, {
        "link.source": "sim", "viser.port": 0,
        "recording.sessions_dir": str(tmp_path), "recording.rate_hz": 20.0,
        "recording.post_disarm_tail_s": 1.0, "recording.min_free_mb": 0}, environ={})
    app = create_app(settings)
    with run_uvicorn(app) as base:
        station = app.state.station
        state = lambda: station.state.get().value if station.state.get() else None  # noqa: E731
        assert wait_until(lambda: state() and state().altitude.reference == "first_fix", 15)
        legs = task_plan(station.twin.scene, 2)
        # Wait on the pad after arming, as a pilot does: the station takes the arming
        # point from the armed HEARTBEAT (1 Hz), before the take-off.
        legs.insert(1, Leg("hold", alt_m=0.0, seconds=1.5))
        pilot = Pilot(legs)
        fly_twin(station.twin, pilot, timeout_s=120)
        assert pilot.done, pilot.log
        assert wait_until(lambda: station.recorder.last_stop is not None
                          and station.recorder.recording_id is None, 20)
        session_id = station.recorder.last_stop.id
        # The live panel drew the flight: the field of the twin's scene and a long trail.
        panel = station.trajectory3d
        assert {"pad:start", "pad:landing"} <= set(panel.scene.field_handles)
        assert panel.trail.n_points > 100 and len(panel.scene.chunk_handles) >= 2
        live_end = np.asarray(panel.scene.vehicle.position)

        reply = httpx.get(f"{base}/api/sessions/{session_id}/trajectory", timeout=30)
        assert reply.status_code == 200, reply.text
        traj = reply.json()

    with open(tmp_path / session_id / layout.TELEMETRY_CSV, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["local_position.x_m"]]
    t_rows = np.array([float(r["t_s"]) for r in rows])
    ned = np.array([[float(r[f"local_position.{k}_m"]) for k in "xyz"] for r in rows])
    armed = np.array([r["heartbeat.armed"] == "True" for r in rows])
    enu_local = np.column_stack([ned[:, 1], ned[:, 0], -ned[:, 2]])
    enu_local -= enu_local[np.argmax(armed)]  # the same origin: where it armed

    t = np.asarray(traj["t_s"])
    got = np.column_stack([traj["x_m"], traj["y_m"], traj["z_m"]])
    want = np.column_stack([np.interp(t, t_rows, enu_local[:, k]) for k in range(3)])
    err = got - want
    horizontal = np.hypot(err[:, 0], err[:, 1])
    print(f"horizontal rms {np.sqrt(np.mean(horizontal**2)):.3f} m, vertical rms "
          f"{np.sqrt(np.mean(err[:, 2] ** 2)):.3f} m over {len(t)} fixes")
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
