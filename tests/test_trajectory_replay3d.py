"""The replay in 3D: a second viser server that draws recorded sessions (real session
folders, real viser, real uvicorn) and moves the vehicle to the slider's instant."""

from __future__ import annotations

import contextlib

import httpx
import msgspec
import numpy as np
import pytest

from fpv_station.core.scene import load_scene
from fpv_station.server.app import create_app
from fpv_station.server.settings import ViserSettings, load_settings
from fpv_station.server.trajectory3d.replay import build_trajectory
from fpv_station.server.trajectory3d.replay_scene import Replay3D
from tests.helpers import run_uvicorn, viser_viewer, wait_until, watch_viser_pushes
from tests.synthetic import SESSION_A, SESSION_B

TOKEN = "replay-test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def straight_line(session_id: str, n: int = 1200, gap_at: int | None = None):
    """A 0.5 m/s east flight at 2 m, 10 Hz, as a trajectory reply (optionally a 3 s gap)."""
    from fpv_station.core.geodesy import enu_to_geodetic

    f = load_scene()
    t = np.arange(n, dtype=np.float64) * 0.1
    enu = np.column_stack([0.5 * t, np.zeros(n), np.full(n, 2.0)])
    lat, lon, alt = enu_to_geodetic(enu, *f.home_llh).T
    if gap_at is not None:
        t[gap_at:] += 3.0
    return build_trajectory(session_id, t, lat, lon, alt, speed_mps=np.full(n, 0.5))


@pytest.fixture
def replay():
    svc = Replay3D(ViserSettings(port=0), host="127.0.0.1", field=load_scene())
    svc.start()
    try:
        yield svc
    finally:
        svc.stop()


def all_segments(svc: Replay3D) -> np.ndarray:
    assert svc.scene is not None
    return np.concatenate([np.asarray(h.points) for h in svc.scene.chunk_handles.values()])


def test_replay_scene_draws_the_path_with_gaps_and_moves_the_vehicle(replay):
    assert replay.port > 0 and replay.scene.chunk_handles == {}
    replay.load(straight_line("a", gap_at=600), straight_line("b", n=300))
    # 1199 steps minus the one across the gap, in chunks of at most 500 segments
    segs = all_segments(replay)
    assert segs.shape == (1198, 2, 3) and len(replay.scene.chunk_handles) == 3
    jumps = np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1)
    assert jumps.max() < 0.06  # no segment drawn across the gap (it would be 0.05 m + 0)
    assert not np.any(
        np.all(np.isclose(segs[:, 0, :1], 29.95, atol=1e-3), axis=1)
        & np.all(np.isclose(segs[:, 1, :1], 30.0, atol=1e-3), axis=1)
    )
    overlay_path = replay.overlay_handles[0]
    assert np.asarray(overlay_path.points).shape == (299, 2, 3)
    # time: the vehicle and the overlay's marker move to the instant, clamped to the flight
    np.testing.assert_allclose(
        replay.scene.vehicle.position, [0, 0, 0], atol=0.01
    )  # origin: the first fix
    assert replay.set_time(10.0) == 10.0
    np.testing.assert_allclose(replay.scene.vehicle.position, [5.0, 0, 0], atol=0.06)
    np.testing.assert_allclose(replay.overlay_vehicle.position, [5.0, 0, 0], atol=0.06)
    fp = np.asarray(replay.scene._footprint.points)
    assert fp.shape == (4, 2, 3) and abs(fp[:, :, 0].mean() - 5.0) < 0.1  # under the body
    np.testing.assert_allclose(fp[:, :, 2], -2.0 + 0.03, atol=0.01)  # on the field, 2 m below
    # nose along the travel (east): the body's +x maps onto +x of ENU
    import viser.transforms as vtf

    R = vtf.SO3(np.asarray(replay.scene.vehicle.wxyz)).as_matrix()
    np.testing.assert_allclose(R @ [1, 0, 0], [1, 0, 0], atol=1e-6)
    assert replay.set_time(1e6) == pytest.approx(replay.primary.duration_s)
    assert replay.set_time(float("nan")) == 0.0
    # a new load replaces the drawn sessions: no overlay, fresh chunks
    replay.load(straight_line("c", n=50))
    assert all_segments(replay).shape == (49, 2, 3) and replay.overlay_handles == []


def replay_settings(two_sessions_dir, **overrides):
    """A station with its 3D panels on and `two_sessions_dir`'s recorded sessions."""
    return load_settings(
        environ={},
        overrides={
            "link.source": "none",
            "viser.port": 0,
            "recording.sessions_dir": str(two_sessions_dir),
            "recording.auto_record_on_arm": False,
            **overrides,
        },
    )


@pytest.fixture
def base(two_sessions_dir):
    settings = replay_settings(two_sessions_dir)
    app = create_app(settings)
    with run_uvicorn(app) as url:
        yield url, app


def test_replay3d_endpoints_load_sessions_and_set_time(base):
    url, app = base
    info = httpx.get(f"{url}/api/viser").json()
    replay = app.state.station.replay3d
    assert info["replay_port"] == replay.port and info["replay_port"] != info["port"]
    # the replay panel serves its own viser client
    assert httpx.get(f"http://127.0.0.1:{info['replay_port']}/").status_code == 200
    r = httpx.put(
        f"{url}/api/replay3d",
        json={"session": SESSION_A, "overlay": SESSION_B, "align": "farthest"},
        timeout=30,
    )
    assert r.status_code == 200, r.text
    j = r.json()
    assert j["session"] == SESSION_A and j["overlay"] == SESSION_B and j["segments"] > 300
    assert len(replay.scene.chunk_handles) >= 1 and replay.overlay_handles
    # the same path as the 2D replay's endpoint draws
    traj = httpx.get(f"{url}/api/sessions/{SESSION_A}/trajectory?align=farthest").json()
    assert j["segments"] == sum(1 for s in traj["starts_run"][1:] if not s)
    t = httpx.put(f"{url}/api/replay3d/time", json={"t_s": 30.0})
    assert t.status_code == 200 and t.json()["t_s"] == 30.0
    i = max(k for k, ts in enumerate(traj["t_s"]) if ts <= 30.0)  # the session clock
    np.testing.assert_allclose(
        replay.scene.vehicle.position, [traj["x_m"][i], traj["y_m"][i], traj["z_m"][i]], atol=0.01
    )


def test_replay_scene_is_changed_only_on_visers_own_loop(base, monkeypatch):
    """viser wakes its senders with an Event of its own loop, set by the thread that
    changes the scene; from another thread that races its viewers' waits ("deque mutated
    during iteration", server/trajectory3d/viser_loop.py). Every message the replay panel
    queues, from its start, its loads and its instants, with viewers watching, is queued
    on viser's loop."""
    import fpv_station.server.trajectory3d.replay_scene as replay_module

    url, app = base
    foreign = watch_viser_pushes(monkeypatch, replay_module)
    assert httpx.get(f"{url}/api/viser").status_code == 200  # the panels start
    replay = app.state.station.replay3d
    with contextlib.ExitStack() as viewers:
        for _ in range(4):
            viewers.enter_context(viser_viewer(replay.port))
        assert wait_until(lambda: len(replay.server.get_clients()) == 4, 20)
        body = {"session": SESSION_A, "overlay": SESSION_B, "align": "farthest"}
        assert httpx.put(f"{url}/api/replay3d", json=body, timeout=60).status_code == 200
        for t in np.linspace(0.0, 45.0, 40):  # within the session (49.8 s)
            r = httpx.put(f"{url}/api/replay3d/time", json={"t_s": float(t)}, timeout=30)
            assert r.status_code == 200 and r.json()["t_s"] == pytest.approx(t)
        # A viewer clicks "Frame the path": viser runs the click on its worker pool, and
        # the clicking viewer's camera is moved to the framing.
        with viser_viewer(replay.port) as ws:
            assert wait_until(lambda: len(replay.server.get_clients()) == 5, 20)
            (frame_button,) = replay.viewer_inputs()
            clients = replay.server.get_clients()
            clicking = clients[max(clients)]  # the newest viewer
            ws.send(
                msgspec.msgpack.encode(
                    {"type": "GuiUpdateMessage", "uuid": frame_button, "updates": {"value": True}}
                )
            )
            _, eye = replay._framing
            assert not np.allclose(clicking.camera.position, eye, atol=1e-3)
            assert wait_until(lambda: np.allclose(clicking.camera.position, eye, atol=1e-3), 20)
    assert foreign == [], foreign[:5]


def test_replay3d_endpoints_refuse_bad_input(base):
    url, app = base
    r = httpx.put(f"{url}/api/replay3d/time", json={"t_s": 1.0})
    assert r.status_code == 400 and r.json()["error"] == "BadRequest"  # nothing loaded yet
    r = httpx.put(f"{url}/api/replay3d", json={"session": "20991122T040000Z_sim"})
    assert r.status_code == 404 and r.json()["error"] == "NotFound"
    r = httpx.put(
        f"{url}/api/replay3d", json={"session": SESSION_A, "overlay": "20991122T040000Z_sim"}
    )
    assert r.status_code == 404 and r.json()["error"] == "NotFound"
    r = httpx.put(f"{url}/api/replay3d", json={"session": "../../etc/passwd"})
    assert r.status_code in (400, 404) and "error" in r.json()
    r = httpx.put(f"{url}/api/replay3d", json={"session": SESSION_A, "reference": "abc"})
    assert r.status_code == 400 and r.json()["error"] == "BadRequest"
    r = httpx.put(f"{url}/api/replay3d/time", json={"t_s": "soon"})
    assert r.status_code == 422
    assert app.state.station.replay3d.primary is None  # nothing half-loaded


def test_replay3d_is_off_with_no_3d(two_sessions_dir):
    settings = load_settings(
        environ={},
        overrides={
            "link.source": "none",
            "viser.enabled": False,
            "recording.sessions_dir": str(two_sessions_dir),
            "recording.auto_record_on_arm": False,
        },
    )
    with run_uvicorn(create_app(settings)) as url:
        r = httpx.put(f"{url}/api/replay3d", json={"session": SESSION_A})
        assert r.status_code == 503 and r.json()["error"] == "Unavailable"


def test_replay_port_defaults_to_live_port_plus_one():
    assert ViserSettings(port=8080).replay_port_resolved == 8081
    assert ViserSettings(port=0).replay_port_resolved == 0
    assert ViserSettings(port=8080, replay_port=9000).replay_port_resolved == 9000


def test_replay_scene_turns_the_field_with_the_papers_alignment(replay):
    """A flight due north, aligned start-to-end on +x: the field turns with it (-90 deg)."""
    from fpv_station.core.geodesy import enu_to_geodetic

    f = load_scene()
    t = np.arange(100) * 0.1
    enu = np.column_stack([np.full(100, 5.0), t, np.full(100, 2.0)])  # 5 m east of the anchor
    lat, lon, alt = enu_to_geodetic(enu, *f.home_llh).T
    replay.load(build_trajectory("n", t, lat, lon, alt, align="end"))
    assert replay.primary.align_rad == pytest.approx(-np.pi / 2, abs=1e-3)
    frame = replay.scene._field_frame
    # the anchor lies 5 m west of the origin; after turning -90 deg that is +y (north)
    np.testing.assert_allclose(frame.position, [0.0, 5.0, -2.0], atol=0.02)
    np.testing.assert_allclose(np.abs(frame.wxyz), [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-3)
    assert frame.wxyz[3] * frame.wxyz[0] < 0  # a clockwise turn
    np.testing.assert_allclose(all_segments(replay)[-1, 1], [9.9, 0.0, 0.0], atol=0.02)


@pytest.mark.timeout(240)  # the viewer renders in software here
def test_replay_viewer_shows_a_users_panel_and_frames_the_path(replay):
    """In Chromium: viser's developer controls (Save Canvas, the scene tree) stay hidden
    behind the panel's own GUI, and the viewer's camera looks at the path's centre."""
    from playwright.sync_api import expect

    from tests.helpers import chromium, wait_until

    replay.load(straight_line("a"), straight_line("b", n=300))
    path = np.concatenate([replay.primary.enu_m, replay.overlay.enu_m])
    centre = (path.min(axis=0) + path.max(axis=0)) / 2
    assert centre[0] == pytest.approx(29.975, abs=0.01)  # 0.5 m/s for 120 s, east

    def cameras():
        return [c.camera for c in replay.server.get_clients().values()]

    with chromium() as browser:
        page = browser.new_page(viewport={"width": 640, "height": 480})
        page.goto(f"http://127.0.0.1:{replay.port}/")
        page.locator("canvas").first.wait_for(timeout=90_000)
        frame_button = page.get_by_role("button", name="Frame the path")
        expect(frame_button).to_be_visible(timeout=90_000)
        expect(page.get_by_text("a with b, 120 s")).to_be_visible()
        for dev in ("Save Canvas", "Scene tree", "Dev Settings", "Reset View"):
            expect(page.get_by_text(dev).first).to_be_hidden(timeout=15_000)  # (folds away)
        # The client's camera, as the browser reports it back: on the path's centre.
        assert wait_until(
            lambda: cameras() and np.allclose(cameras()[0].look_at, centre, atol=0.5), 30
        ), [c.look_at for c in cameras()]
        # The pilot looks away; the panel's button brings the whole path back.
        cam = cameras()[0]
        cam.position, cam.look_at = (100.0, 100.0, 50.0), (80.0, 80.0, 0.0)
        assert wait_until(lambda: np.allclose(cameras()[0].look_at, (80, 80, 0), atol=0.5), 30)
        frame_button.click()
        assert wait_until(lambda: np.allclose(cameras()[0].look_at, centre, atol=0.5), 30), (
            cameras()[0].look_at
        )


def test_replay3d_changes_need_the_control_token(two_sessions_dir):
    """What the replay panel shows is shared by all its viewers: only the token moves it."""
    app = create_app(replay_settings(two_sessions_dir, **{"server.token": TOKEN}))
    with run_uvicorn(app) as url:
        load = {"session": SESSION_A}
        for headers in ({}, {"Authorization": "Bearer wrong-token"}):
            r = httpx.put(f"{url}/api/replay3d", json=load, headers=headers, timeout=30)
            assert r.status_code == 401 and r.json()["error"] == "Unauthorized"
        replay = app.state.station.replay3d
        assert replay is None or replay.primary is None  # nothing drawn for a stranger
        r = httpx.put(f"{url}/api/replay3d", json=load, headers=AUTH, timeout=30)
        assert r.status_code == 200 and r.json()["session"] == SESSION_A
        replay = app.state.station.replay3d
        r = httpx.put(f"{url}/api/replay3d/time", json={"t_s": 30.0})
        assert r.status_code == 401 and replay.t_s == 0.0
        r = httpx.put(f"{url}/api/replay3d/time", json={"t_s": 30.0}, headers=AUTH)
        assert r.status_code == 200 and replay.t_s == 30.0
