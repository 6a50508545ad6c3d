"""One recorded twin flight, end to end (a real station on the twin, real MAVLink over
loopback, the twin's rendered cameras): its trajectory matches the twin's own positions,
and one clock runs in every view of the session, read through every path that shows it:
telemetry.csv's rows, the cameras' frames.csv, the trajectory route, the 3D replay scene
(through its route) and the replay page in headless Chromium. At sampled instants of the
session clock they must agree: the path's position is the row's, and the frame shown is
the newest captured at or before the instant, no older than one frame period."""

from __future__ import annotations

import csv

import httpx
import numpy as np
import pytest

from fpv_station.analysis.track import load_session_dir
from fpv_station.companion.recording import layout
from fpv_station.core.geodesy import geodetic_to_enu
from tests.helpers import chromium, viser_viewer, wait_until
from tests.pages import open_offline
from tests.twin_flights import SMALL_CAMERAS, recorded_twin_flight

INSTANTS = 80  # sampled instants of the session clock


def read_rows(folder) -> dict[str, np.ndarray]:
    with open(folder / layout.TELEMETRY_CSV, newline="") as f:
        rows = list(csv.DictReader(f))
    cols = ("t_s", "gps.fix_type", "gps.lat_deg", "gps.lon_deg", "gps.alt_m")
    return {c: np.array([float(r[c]) if r[c] else np.nan for r in rows]) for c in cols} | {
        f"{cam}.file": np.array([r[f"{cam}.file"] for r in rows]) for cam in layout.CAMERAS
    }


def read_frames(folder, camera: str) -> tuple[np.ndarray, list[str]]:
    with open(folder / layout.frames_csv_relpath(camera), newline="") as f:
        rows = list(csv.DictReader(f))
    return np.array([float(r["t_s"]) for r in rows]), [r["file"] for r in rows]


def last_at_or_before(times: np.ndarray, t: float) -> int:
    return int(np.searchsorted(times, t, side="right")) - 1


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """Task 2 flown on the twin by a real station that recorded it (rows at 20 Hz, its 3D
    panels on) and still runs: one flight read by both tests."""
    overrides = {
        "viser.enabled": True,
        "viser.port": 0,
        "recording.rate_hz": 20.0,
        **SMALL_CAMERAS,
    }
    with recorded_twin_flight(tmp_path_factory.mktemp("sessions"), 2, overrides) as flight:
        yield flight


@pytest.mark.timeout(400)  # the module's flight is made first
def test_twin_session_trajectory_matches_local_position(flight):
    """The trajectory endpoint turns the recorded GPS into ENU about the arming point,
    and that matches the twin's own LOCAL_POSITION_NED (recorded in the same rows) within
    GPS noise. The live 3D panel drew the same flight meanwhile."""
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

    with open(flight.folder / layout.TELEMETRY_CSV, newline="") as f:
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


@pytest.mark.timeout(400)
def test_path_rows_and_frames_agree_on_the_session_clock(flight):
    base, sid, station = flight.base_url, flight.session_id, flight.station
    rows, folder = read_rows(flight.folder), flight.folder
    frames = {cam: read_frames(folder, cam) for cam in layout.CAMERAS}
    reply = httpx.get(f"{base}/api/sessions/{sid}/trajectory", timeout=60)
    assert reply.status_code == 200, reply.text
    traj = reply.json()

    # The instants: anywhere in the session, and right at and just after rows.
    rng = np.random.default_rng(7)
    t_rows = rows["t_s"]
    instants = np.concatenate(
        [
            rng.uniform(0.0, t_rows[-1], INSTANTS),
            rng.choice(t_rows, INSTANTS // 4),
            rng.choice(t_rows, INSTANTS // 4) + 0.001,
        ]
    )
    o = traj["origin"]
    row_enu = geodetic_to_enu(
        rows["gps.lat_deg"], rows["gps.lon_deg"], rows["gps.alt_m"],
        o["lat_deg"], o["lon_deg"], o["alt_m"],
    )  # fmt: skip
    path_t = np.asarray(traj["t_s"])
    path_enu = np.column_stack([traj["x_m"], traj["y_m"], traj["z_m"]])
    has_fix = rows["gps.fix_type"] >= 3
    assert has_fix.mean() > 0.9 and traj["duration_s"] >= t_rows[has_fix][-1]
    # The path starts where the rows first hold a fix, not seconds away from it.
    assert path_t[0] == pytest.approx(t_rows[np.argmax(has_fix)], abs=1e-6)

    # Analysis measures on the vehicle's spacing, placed on the same clock: a sample
    # was taken no later than the row that first held it, and not long before.
    track = load_session_dir(folder)
    np.testing.assert_allclose(track.row_t_s, path_t, atol=1e-6)
    early = track.row_t_s - track.t_s
    assert early.min() >= 0.0 and early.max() < 1.0, (early.min(), early.max())

    period = {cam: float(np.median(np.diff(frames[cam][0]))) for cam in layout.CAMERAS}
    worst = {"path_m": 0.0}
    worst |= {f"{cam}_{w}": 0 for cam in layout.CAMERAS for w in ("age_s", "row_frames")}
    for t in instants:
        k = last_at_or_before(t_rows, t)  # the row of the instant
        i = last_at_or_before(path_t, t)  # the path's fix of the instant
        if k >= 0 and has_fix[k]:
            assert i >= 0, t
            err = float(np.abs(path_enu[i] - row_enu[k]).max())
            worst["path_m"] = max(worst["path_m"], err)
            assert err < 0.002, (t, path_enu[i], row_enu[k])  # the reply's mm rounding
        else:
            assert i < 0, t
        for cam in layout.CAMERAS:
            times, files = frames[cam]
            index = traj["frame_index"][cam]
            j = last_at_or_before(np.asarray(index["t_s"]), t)
            if j < 0:
                assert t < times[0]
                continue
            # The frame shown: the newest captured at or before the instant...
            assert index["file"][j] == files[last_at_or_before(times, t)]
            # ...and the next one after it: within one frame period of the instant.
            assert index["t_s"][j] <= t and (j + 1 == len(times) or times[j + 1] > t)
            worst[f"{cam}_age_s"] = max(worst[f"{cam}_age_s"], t - index["t_s"][j])
            # The row names the frame shown at the row's own instant, or one a frame
            # period from it (the recorder samples the cameras at its own instants).
            if k >= 0 and rows[f"{cam}.file"][k]:
                named = files.index(rows[f"{cam}.file"][k])
                j_row = last_at_or_before(times, t_rows[k])
                off = abs(named - j_row)
                worst[f"{cam}_row_frames"] = max(worst[f"{cam}_row_frames"], off)
                assert off <= 1, (cam, t_rows[k], files[named], files[j_row])
            # The row of a fix names the frame the trajectory shows at that fix.
            if i >= 0 and k >= 0:
                j_fix = last_at_or_before(times, path_t[i])
                assert traj["frames"][cam][i] == (files[j_fix] if j_fix >= 0 else None)
    print(f"worst over {len(instants)} instants: {worst}, frame periods {period}")

    # The 3D replay scene, moved through its route, puts the vehicle on the row's fix.
    put = httpx.put(f"{base}/api/replay3d", json={"session": sid}, timeout=120)
    assert put.status_code == 200, put.text
    assert put.json()["duration_s"] == pytest.approx(traj["duration_s"])
    scene = station.replay3d
    for t in instants[:20]:
        state = httpx.put(f"{base}/api/replay3d/time", json={"t_s": float(t)}, timeout=30)
        assert state.json()["t_s"] == pytest.approx(t)
        k = last_at_or_before(t_rows, t)
        assert scene.scene.vehicle.visible == bool(k >= 0 and has_fix[k])
        if k >= 0 and has_fix[k]:
            np.testing.assert_allclose(scene.scene.vehicle.position, row_enu[k], atol=0.002)

    # The replay page: its slider and clock read on the same axis, its readout and
    # frames are the row's and the frame's of that instant, and it moves the 3D scene.
    outside: list[str] = []
    with chromium() as browser:
        page = open_offline(browser, outside)
        # Not the 3D panel's WebGL client (software rendering here): its scene is
        # checked through station.replay3d, which the page moves through the route.
        page.route("**/3d/**", lambda route: route.abort())
        page.goto(f"{base}/replay.html?session={sid}")
        page.wait_for_function(
            "document.getElementById('replay-status').textContent.includes('fixes')",
            timeout=60_000,
        )
        slider = page.locator("#replay-slider")
        # tenths of a second, rounded by the page (Math.round, not Python's round)
        assert abs(int(slider.get_attribute("max")) - traj["duration_s"] * 10) <= 0.5
        for tenth in (0, 3, int(t_rows[-1] * 5), int(t_rows[-1] * 10) - 7):
            t = tenth / 10
            slider.evaluate(
                f"el => {{ el.value = {tenth}; el.dispatchEvent(new Event('input')); }}"
            )
            assert page.locator("#replay-time").text_content().startswith(f"{t:.1f} /")
            k = last_at_or_before(t_rows, t)
            assert has_fix[k]
            # Shown in cm: the row's height, to the display's rounding (of the reply's mm).
            height = float(page.locator("#r-z").text_content().removesuffix(" m"))
            assert abs(height - row_enu[k][2]) <= 0.0051 + 0.0005, (t, height, row_enu[k])
            for cam in layout.CAMERAS:
                times, files = frames[cam]
                j = last_at_or_before(times, t)
                src = page.locator(f"#replay-{cam}").get_attribute("src")
                if j < 0:  # the session starts before a camera's first frame
                    assert src is None, (t, cam, src)
                else:
                    assert src is not None and src.endswith(files[j]), (t, cam, src)
            # A hang guard: the page sends an instant once the station answered the last.
            assert wait_until(lambda t=t: abs(station.replay3d.t_s - t) < 1e-6, 60)
    assert outside == [], outside[:5]
