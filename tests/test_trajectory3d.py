"""The live 3D trajectory: pose math, the chunked trail, and a real viser server fed with
vehicle states through a `Latest`, as the station feeds it."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
import threading
import time

import httpx
import numpy as np
import pytest
import viser.transforms as vtf

from fpv_station.companion.latest import Latest
from fpv_station.companion.vehicle_state import (
    Attitude,
    GlobalPosition,
    GpsRaw,
    PilotAltitude,
    VehicleState,
)
from fpv_station.core.geodesy import enu_to_geodetic
from fpv_station.core.scene import load_scene
from fpv_station.server.app import create_app
from fpv_station.server.settings import ViserSettings, load_settings
from fpv_station.server.trajectory3d.colors import ramp_rgb
from fpv_station.server.trajectory3d.pose import (
    R_enu_flu_from_euler,
    bottom_footprint_enu,
    wxyz_from_matrix,
)
from fpv_station.server.trajectory3d.service import Trajectory3D
from fpv_station.server.trajectory3d.trail import Trail, TrailSample
from tests.helpers import (
    CountingSelector,
    run_uvicorn,
    station_settings,
    viser_viewer,
    wait_until,
    watch_viser_pushes,
)

FIELD = load_scene()
ORIGIN = FIELD.home_llh


def make_state(
    t_s: float,
    enu: tuple[float, float, float],
    fix_type: int = 3,
    yaw_rad: float = 0.0,
    armed_origin: tuple | None = None,
) -> VehicleState:
    """A vehicle state at ENU position `enu` about the field's anchor."""
    lat, lon, alt = (float(v) for v in enu_to_geodetic(enu, *ORIGIN))
    altitude = PilotAltitude()
    if armed_origin is not None:
        altitude = PilotAltitude(
            t_mono=t_s,
            reference="arming",
            home_lat_deg=armed_origin[0],
            home_lon_deg=armed_origin[1],
            reference_alt_m=armed_origin[2],
        )
    return VehicleState(
        gps=GpsRaw(t_mono=t_s, fix_type=fix_type, lat_deg=lat, lon_deg=lon, alt_m=alt),
        global_position=GlobalPosition(
            t_mono=t_s, lat_deg=lat, lon_deg=lon, alt_m=alt, vx_mps=1.0, vy_mps=0.5, vz_mps=0.0
        ),
        attitude=Attitude(t_mono=t_s, roll_rad=0.0, pitch_rad=0.0, yaw_rad=yaw_rad),
        altitude=altitude,
    )


@pytest.fixture
def unwatched_service():
    svc = Trajectory3D(
        ViserSettings(port=0, chunk_segments=20), Latest(), host="127.0.0.1", field=FIELD
    )
    svc.start()
    try:
        yield svc
    finally:
        svc.stop()


@pytest.fixture
def service(unwatched_service):
    """The panel with one viewer: the scene is drawn only while someone watches."""
    with viser_viewer(unwatched_service.port):
        assert wait_until(unwatched_service.watched)
        yield unwatched_service


# -- pose ------------------------------------------------------------------------------


def test_attitude_maps_ned_frd_onto_enu_flu():
    fwd = np.array([1.0, 0.0, 0.0])
    # yaw 0 = nose north, yaw 90 deg = nose east (NED convention)
    np.testing.assert_allclose(R_enu_flu_from_euler(0, 0, 0) @ fwd, [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(R_enu_flu_from_euler(0, 0, math.pi / 2) @ fwd, [1, 0, 0], atol=1e-12)
    # nose up (positive pitch) raises the forward axis
    assert (R_enu_flu_from_euler(0, 0.3, 0) @ fwd)[2] > 0.29
    # right wing down (positive roll) raises the left axis (+y of FLU)
    assert (R_enu_flu_from_euler(0.3, 0, 0) @ np.array([0, 1.0, 0]))[2] > 0.29
    R = R_enu_flu_from_euler(0.2, -0.4, 2.5)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    q = wxyz_from_matrix(R)
    np.testing.assert_allclose(vtf.SO3(q).as_matrix(), R, atol=1e-9)


def test_bottom_footprint_on_the_ground():
    R = R_enu_flu_from_euler(0, 0, math.pi / 2)  # nose east
    c = bottom_footprint_enu(np.array([5.0, 0.0, 4.0]), R, math.radians(90), math.radians(60))
    assert c is not None
    np.testing.assert_allclose(c[:, 2], 0.0)
    # along the nose (east) the half-extent is 4 tan(30 deg), across it 4 tan(45 deg)
    np.testing.assert_allclose(np.ptp(c[:, 0]), 2 * 4 * math.tan(math.radians(30)), atol=1e-9)
    np.testing.assert_allclose(np.ptp(c[:, 1]), 2 * 4.0, atol=1e-9)
    np.testing.assert_allclose(c[:, :2].mean(axis=0), [5.0, 0.0], atol=1e-9)
    # tilted towards the horizon, or on the ground: no footprint
    assert (
        bottom_footprint_enu(
            np.array([0, 0, 4.0]),
            R_enu_flu_from_euler(1.4, 0, 0),
            math.radians(90),
            math.radians(60),
        )
        is None
    )
    assert bottom_footprint_enu(np.array([0, 0, 0.0]), R, 1.0, 1.0) is None


def test_colour_ramp_is_fixed_and_clipped():
    rgb = ramp_rgb([-5.0, 0.0, 10.0, 50.0, np.nan], 0.0, 10.0)
    assert rgb.dtype == np.uint8 and rgb.shape == (5, 3)
    assert (rgb[0] == rgb[1]).all() and (rgb[2] == rgb[3]).all() and (rgb[1] != rgb[2]).any()
    assert tuple(rgb[4]) == (128, 128, 128)


# -- trail -----------------------------------------------------------------------------


def _sample(t, e, n=0.0, u=3.0):
    lat, lon, alt = enu_to_geodetic([e, n, u], *ORIGIN)
    return TrailSample(t, float(lat), float(lon), float(alt), 1.0)


def test_trail_chunks_are_continuous_and_bounded():
    trail = Trail(chunk_segments=10, gap_s=1.0)
    for i in range(101):
        trail.append(_sample(i * 0.1, i * 0.1))
    assert all(c.n_segments <= 10 for c in trail.chunks)
    assert sum(c.n_segments for c in trail.chunks) == 100  # no segment lost at chunk joins
    for a, b in zip(trail.chunks, trail.chunks[1:]):
        np.testing.assert_allclose(a.segments()[0][-1, 1], b.segments()[0][0, 0])


def test_trail_gaps_are_gaps_not_jumps():
    trail = Trail(chunk_segments=100, gap_s=1.0)
    for i in range(10):
        trail.append(_sample(i * 0.1, i * 0.1))
    trail.append(_sample(3.0, 20.0))  # 2 s of silence, 19 m further: a gap
    trail.mark_gap()  # the fix is lost
    trail.append(_sample(3.1, 30.0))
    trail.append(_sample(3.2, 30.1))
    pts = np.concatenate([c.segments()[0] for c in trail.chunks])
    lengths = np.linalg.norm(pts[:, 1] - pts[:, 0], axis=1)
    assert len(pts) == 10 and lengths.max() < 0.2


def test_trail_reprojects_on_a_new_origin_and_drops_old_chunks():
    trail = Trail(chunk_segments=10, gap_s=1.0, max_points=50)
    for i in range(200):
        trail.append(_sample(i * 0.1, i * 0.1))
    assert trail.n_points <= 50 and trail.chunks[0].segments()[0][0, 0, 0] > 13.99
    lat, lon, alt = enu_to_geodetic([10.0, 0.0, 0.0], *ORIGIN)
    assert trail.set_origin((float(lat), float(lon), float(alt)))
    np.testing.assert_allclose(trail.last_enu_m, [19.9 - 10.0, 0.0, 3.0], atol=1e-3)


def _n_segments(trail: Trail) -> int:
    return sum(c.n_segments for c in trail.chunks)


@pytest.mark.parametrize("jitter_m", [0.0, 0.01])
def test_a_parked_vehicle_adds_no_trail_points(jitter_m):
    """A vehicle on its pad, exactly still (the twin) or jittering by a centimetre, for
    10 minutes of states at 15 Hz: one point, however long it sits."""
    trail = Trail(chunk_segments=50, gap_s=1.0, min_step_m=0.05)
    rng = np.random.default_rng(1)
    for i in range(9000):
        e, n, u = rng.uniform(-jitter_m, jitter_m, 3) if jitter_m else (0.0, 0.0, 0.0)
        changed, dropped = trail.append(_sample(i / 15, e, n, 3.0 + u))
        assert dropped == [] and (i == 0 or changed == [])  # nothing to redraw either
    assert trail.n_points == 1 and len(trail.chunks) == 1


def test_a_moving_vehicle_adds_every_state():
    trail = Trail(chunk_segments=50, gap_s=1.0, min_step_m=0.05)
    for i in range(300):  # 1.5 m/s at 15 Hz: 10 cm a state
        trail.append(_sample(i / 15, i * 0.1))
    assert trail.n_points == 300 and _n_segments(trail) == 299


def test_a_vehicle_that_sat_still_continues_its_run_and_ends_it_where_it_was():
    """Parked for 60 s (no point added, but every sample heard) then moving again: the
    same run, no gap drawn. When the run ends (a lost fix), the line ends at the last
    position heard, not at the last point added before it."""
    trail = Trail(chunk_segments=20, gap_s=1.0, min_step_m=0.05)
    t = 0.0
    for i in range(10):  # flying east 10 cm a state
        trail.append(_sample(t, i * 0.1))
        t += 1 / 15
    for _ in range(900):  # sits at 0.9 m for 60 s, creeping 4 cm in all
        trail.append(_sample(t, 0.9 + 0.04 * _ / 900))
        t += 1 / 15
    assert trail.n_points == 10
    for i in range(1, 11):  # flies on east
        trail.append(_sample(t, 0.94 + i * 0.1))
        t += 1 / 15
    assert trail.n_points == 20 and _n_segments(trail) == 19  # one run: no gap
    for _ in range(30):  # sits again, creeping 3 cm
        trail.append(_sample(t, 1.94 + 0.03 * _ / 29))
        t += 1 / 15
    trail.mark_gap()  # the fix is lost
    changed, _ = trail.append(_sample(t + 5.0, 50.0))  # and comes back far away
    pts = np.concatenate([c.segments()[0] for c in trail.chunks])
    assert len(pts) == 20  # the held end joined its run; the new run's first point alone
    np.testing.assert_allclose(pts[-1, 1, 0], 1.97, atol=1e-3)
    assert trail.chunks[-1] in changed and len(changed) == 2  # the full chunk, a new one


def test_a_trail_point_costs_a_few_dozen_bytes():
    """A moving vehicle gives the live trail `update_hz` points a second (up to
    `max_points`): each point, drawn or not, holds about 60 bytes of arrays (a
    tuple, a float and an array view per point held about five times that)."""
    import tracemalloc

    trail = Trail(chunk_segments=50, gap_s=1.0)
    samples = [
        _sample(i / 15, i * 0.05, math.sin(i / 40), 3.0 + (i % 7) * 0.1) for i in range(6000)
    ]
    tracemalloc.start()
    try:
        for i, s in enumerate(samples):
            changed, _ = trail.append(s)
            if i % 4 == 0:  # drawn as a watched panel draws it: projected as it comes
                for chunk in changed:
                    chunk.segments()
        for chunk in trail.chunks:
            chunk.segments()
        held, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert trail.n_points == 6000
    assert held / trail.n_points < 100, held / trail.n_points


# -- the scene on a real viser server ----------------------------------------------------


def test_scene_gains_segments_while_the_vehicle_moves(service):
    state: Latest[VehicleState] = Latest()
    service.state = state

    async def fly() -> list[int]:
        task = asyncio.create_task(service.run())
        seen = []
        for i in range(150):
            state.publish(make_state(i * 0.1, (i * 0.2, 0.0, 3.0)))
            await asyncio.sleep(0.012)
            seen.append(len(service.scene.chunk_handles))
        state.close()
        await asyncio.wait_for(task, 2.0)
        return seen

    t0 = time.monotonic()
    seen = asyncio.run(fly())
    elapsed_s = time.monotonic() - t0
    # 150 states at about 80 Hz, drawn at the 15 Hz cap: rate-limited, not per packet
    assert 10 <= service.steps <= elapsed_s * 15 + 3
    assert seen[-1] >= 2 and seen == sorted(seen)  # chunks only ever get added
    handles = service.scene.chunk_handles
    pts = np.concatenate([h.points for h in handles.values()])
    assert len(pts) == service.steps - 1
    # what the scene holds is the flown line, about the first fix: y = 0, z = 0, x growing
    np.testing.assert_allclose(pts[:, :, 1], 0.0, atol=0.05)
    np.testing.assert_allclose(pts[:, :, 2], 0.0, atol=0.05)
    assert (np.diff(pts[:, 1, 0]) > 0).all()
    np.testing.assert_allclose(service.scene.vehicle.position[0], pts[:, :, 0].max(), atol=0.3)
    # the scene's own node tree holds them too
    assert all(h.name.startswith("/trail/c") for h in handles.values())


def test_a_parked_vehicle_does_not_grow_the_panel(service):
    """The station's default settings, a viewer watching, 20 s of states of a vehicle on
    its pad jittering by a centimetre: one trail point, nothing more drawn, and the
    vehicle drawn where it is, not at the trail's last point."""
    rng = np.random.default_rng(2)
    for i in range(300):
        e, n, u = rng.uniform(-0.01, 0.01, 3) if i else (0.0, 0.0, 0.0)
        service.step(make_state(i / 15, (5.0 + e, 2.0 + n, 3.0 + u)))
    assert service.trail.n_points == 1 and service.scene.chunk_handles == {}
    service.step(make_state(20.0, (5.04, 2.0, 3.0)))  # 4 cm east: still parked
    assert service.trail.n_points == 1
    first = service.trail.chunks[0]
    np.testing.assert_allclose(
        service.scene.vehicle.position - first.last_enu_m, (0.04, 0, 0), atol=2e-3
    )


def test_an_unwatched_panel_keeps_the_trail_and_draws_it_for_the_first_viewer(
    unwatched_service,
):
    service = unwatched_service
    before = service.server._websock_server.get_message_buffer().message_counter
    for i in range(45):  # more than two chunks of 20 segments
        service.step(make_state(i * 0.1, (i * 0.2, 0.0, 3.0)))
    assert service.trail.n_points == 45 and len(service.trail.chunks) == 3
    assert service.scene.chunk_handles == {}  # nothing drawn, nothing sent
    assert service.server._websock_server.get_message_buffer().message_counter == before
    with viser_viewer(service.port):
        assert wait_until(service.watched)
        service.step(make_state(4.5, (9.0, 0.0, 3.0)))
        pts = np.concatenate([h.points for h in service.scene.chunk_handles.values()])
        assert len(pts) == 45  # the whole flight: 46 fixes, 45 segments
        np.testing.assert_allclose(pts[:, 1, 0].max(), 9.0, atol=1e-3)
        # about the first fix: x along the flight, the same height
        np.testing.assert_allclose(service.scene.vehicle.position, (9.0, 0.0, 0.0), atol=1e-3)
    assert wait_until(lambda: not service.watched())
    for i in range(46, 60):  # the viewer left: the trail grows, the scene waits again
        service.step(make_state(i * 0.1, (i * 0.2, 0.0, 3.0)))
    drawn = np.concatenate([h.points for h in service.scene.chunk_handles.values()])
    assert service.trail.n_points == 60 and len(drawn) == 45


def test_a_viewer_without_telemetry_gets_the_trail_drawn(unwatched_service):
    service = unwatched_service
    for i in range(10):
        service.step(make_state(i * 0.1, (i * 0.2, 0.0, 3.0)))

    async def idle_until_drawn() -> bool:
        task = asyncio.create_task(service.run())  # nothing is published: no telemetry
        try:
            with viser_viewer(service.port):
                for _ in range(100):
                    await asyncio.sleep(0.02)
                    if service.scene.chunk_handles:
                        return True
                return False
        finally:
            service.state.close()
            await asyncio.wait_for(task, 2.0)

    assert asyncio.run(idle_until_drawn())
    pts = np.concatenate([h.points for h in service.scene.chunk_handles.values()])
    assert len(pts) == 9


def test_a_first_viewer_gets_a_long_trail_without_holding_the_loop(unwatched_service):
    """Building a chunk's handle costs viser a few milliseconds (more on a Pi): a long
    flight's trail drawn at once for its first viewer held the station's event loop
    (video, telemetry, control) for seconds. It is drawn a few chunks at a time, and the
    loop serves others between them."""
    service = unwatched_service
    for i in range(400):  # 20 chunks of 20 segments
        service.step(make_state(i * 0.1, (i * 0.2, 0.0, 3.0)))
    total = len(service.trail.chunks)

    async def watch() -> list[int]:
        task = asyncio.create_task(service.run())  # nothing is published: no telemetry
        seen: list[int] = []  # chunks drawn, as another task on the loop sees them
        try:
            with viser_viewer(service.port):
                deadline = time.monotonic() + 60
                while time.monotonic() < deadline and (not seen or seen[-1] < total):
                    await asyncio.sleep(0)
                    n = len(service.scene.chunk_handles)
                    if not seen or seen[-1] != n:
                        seen.append(n)
        finally:
            service.state.close()
            await asyncio.wait_for(task, 2.0)
        return seen

    seen = asyncio.run(watch())
    assert seen[-1] == total
    assert any(0 < n < total for n in seen), seen  # the loop ran while the trail was drawn


def test_an_unwatched_panel_keeps_the_trail_without_waking_the_loop_for_each_state(
    unwatched_service,
):
    """Nobody looks: the states for the trail are kept by the slot's listener, 15 a
    second, and the loop takes them once a second (it woke 15 times a second); the first
    viewer gets them all drawn."""
    service = unwatched_service
    stop = threading.Event()

    def vehicle() -> None:  # 50 states a second, flying east
        i = 0
        while not stop.wait(0.02):
            service.state.publish(make_state(i * 0.02, (i * 0.02, 0.0, 3.0)))
            i += 1

    selector = CountingSelector()

    async def fly() -> tuple[int, int, int]:
        task = asyncio.create_task(service.run())
        try:
            await asyncio.sleep(0.5)
            turns = selector.turns
            await asyncio.sleep(2.0)
            quiet_turns = selector.turns - turns
            await asyncio.sleep(1.2)  # the last second's states are taken
            kept = service.trail.n_points
            with viser_viewer(service.port):
                # viser's loop adds the chunks' handles one by one (a redraw of a few per
                # turn): wait for the whole trail, up to a hang guard.
                for _ in range(200):
                    await asyncio.sleep(0.05)
                    handles = list(service.scene.chunk_handles.values())
                    drawn = sum(len(h.points) for h in handles)
                    if drawn >= kept - 1:
                        break
            return quiet_turns, kept, drawn
        finally:
            service.state.close()
            await asyncio.wait_for(task, 3.0)

    thread = threading.Thread(target=vehicle, daemon=True)
    thread.start()
    loop = asyncio.SelectorEventLoop(selector)
    try:
        quiet_turns, kept, drawn = loop.run_until_complete(fly())
    finally:
        loop.close()
        stop.set()
        thread.join(5)
    assert quiet_turns <= 10  # two seconds: two takes, 6 here (60 before)
    assert kept >= 0.5 * 15 * 3.0  # about 15 states a second for 3.7 s: half, under load
    assert drawn >= kept - 1  # the viewer got the whole trail (segments: points - 1)


def test_origin_moves_to_the_arming_point(service):
    service.step(make_state(0.0, (0.0, 0.0, 0.0)))
    service.step(make_state(0.1, (0.5, 0.0, 1.0)))
    assert np.allclose(service.scene.vehicle.position, (0.5, 0.0, 1.0), atol=1e-3)
    lat, lon, alt = enu_to_geodetic([-20.0, 0.0, 0.0], *ORIGIN)  # armed on the start pad
    armed = (float(lat), float(lon), float(alt))
    service.step(make_state(0.2, (1.0, 0.0, 2.0), armed_origin=armed))
    assert np.allclose(service.scene.vehicle.position, (21.0, 0.0, 2.0), atol=1e-3)
    handle = next(iter(service.scene.chunk_handles.values()))
    assert np.allclose(handle.points[0, 0], (20.0, 0.0, 0.0), atol=1e-3)  # re-projected
    assert np.allclose(service.scene._field_frame.position, (20.0, 0.0, 0.0), atol=1e-3)


def test_gui_requests_clear_and_recolour(service):
    for i in range(30):
        service.step(make_state(i * 0.1, (i * 0.1, 0.0, i * 0.2)))
    chunk = next(iter(service.scene.chunk_handles.values()))
    by_height = chunk.colors.copy()
    service.controls._requests.color_by = "speed"  # what a pilot's pick records
    service.step(make_state(3.0, (3.0, 0.0, 6.0)))
    assert not np.array_equal(chunk.colors, by_height)
    assert service.controls.color_by == "speed"
    service.controls._requests.field_visible = False
    service.controls._requests.clear = True  # what the button's click callback records
    service.step(make_state(3.1, (3.1, 0.0, 6.0)))
    assert not service.scene._field_frame.visible
    assert service.trail.n_points == 1 and len(service.scene.chunk_handles) == 0


def _array_bytes(obj) -> int:
    """Bytes of the numpy payloads in a viser message (its dataclass fields, recursively)."""
    if isinstance(obj, np.ndarray):
        return obj.nbytes
    if dataclasses.is_dataclass(obj):
        return sum(_array_bytes(getattr(obj, f.name)) for f in dataclasses.fields(obj))
    if isinstance(obj, dict):
        return sum(_array_bytes(v) for v in obj.values())
    return 0


def test_update_cost_stays_flat_over_a_30_minute_flight(service):
    """18,000 states (30 min at 10 Hz, with GPS dropouts): the messages and array bytes
    queued for viewers per step must not grow with the length of the flight."""
    buffer = service.server._websock_server.get_message_buffer()  # what viewers receive
    counts, sizes = [], []
    rng = np.random.default_rng(1)
    t = np.arange(18_000) * 0.1
    enu = np.stack([10 * np.sin(t / 30), 6 * np.sin(t / 15), 3 + rng.normal(0, 0.3, t.size)], 1)
    geo = enu_to_geodetic(enu, *ORIGIN)
    for i in range(t.size):
        fix = 1 if (i % 3000) < 20 else 3  # a 2 s dropout every 5 minutes
        ti, (lat, lon, alt) = float(t[i]), (float(v) for v in geo[i])
        state = VehicleState(
            gps=GpsRaw(t_mono=ti, fix_type=fix, lat_deg=lat, lon_deg=lon, alt_m=alt),
            global_position=GlobalPosition(
                t_mono=ti, lat_deg=lat, lon_deg=lon, alt_m=alt, vx_mps=1.0, vy_mps=0.0
            ),
            attitude=Attitude(t_mono=ti, roll_rad=0.0, pitch_rad=0.0, yaw_rad=ti / 10),
        )
        first_id = buffer.message_counter
        service.step(state)
        new_ids = range(first_id, buffer.message_counter)
        counts.append(len(new_ids))
        sizes.append(sum(_array_bytes(buffer.message_from_id.get(m)) for m in new_ids))
    counts, sizes = np.array(counts), np.array(sizes)
    first, last = slice(100, 3100), slice(15_000, 18_000)  # minute 0-5 vs. minute 25-30
    assert counts.max() <= 8
    assert counts[last].mean() <= counts[first].mean() * 1.05
    assert sizes[last].mean() <= sizes[first].mean() * 1.05
    assert 0 < sizes.max() < 4_000  # one open chunk of 20 segments, never the whole path
    assert len(service.scene.chunk_handles) > 18_000 // 20 * 0.9


# -- the panel in the app ----------------------------------------------------------------


def test_panel_starts_and_stops_with_the_station():
    settings = load_settings(environ={}, overrides={"link.source": "none", "viser.port": 0})
    with run_uvicorn(create_app(settings)) as base:
        info = httpx.get(f"{base}/api/viser").json()
        assert info["enabled"] is True and info["port"] > 0
        page = httpx.get(f"http://127.0.0.1:{info['port']}/")
        assert page.status_code == 200 and "<html" in page.text.lower()
    with pytest.raises(httpx.ConnectError):  # the viser server is gone with the station
        httpx.get(f"http://127.0.0.1:{info['port']}/", timeout=2.0)


def test_a_visit_after_the_station_stopped_starts_no_panel(tmp_path):
    from fpv_station.server.station import open_station, start_3d_panels

    settings = station_settings("none", tmp_path, **{"viser.enabled": True, "viser.port": 0})

    async def visit_late():
        async with open_station(settings) as station:
            assert station.trajectory3d is not None and station.trajectory3d.server is None
        await start_3d_panels(station)  # a request that arrives during shutdown
        return station

    station = asyncio.run(visit_late())
    assert station.trajectory3d.server is None and station.replay3d is None


def test_no_3d_flag():
    from fpv_station.server.cli import build_parser, settings_from_args

    args = build_parser().parse_args(["serve", "--no-3d", "--viser-port", "8090"])
    settings = settings_from_args(args)
    assert settings.viser.enabled is False and settings.viser.port == 8090
    assert settings.viser.replay_port_resolved == 8091
    args = build_parser().parse_args(["serve", "--viser-replay-port", "9100"])
    assert settings_from_args(args).viser.replay_port_resolved == 9100
    settings = load_settings(environ={}, overrides={"link.source": "none", "viser.enabled": False})
    with run_uvicorn(create_app(settings)) as base:
        assert httpx.get(f"{base}/api/viser").json() == {
            "enabled": False,
            "path": None,
            "replay_path": None,
            "port": None,
            "points": 0,
            "chunks": 0,
            "replay_port": None,
        }
        assert httpx.get(f"{base}/3d/live/").status_code == 404


def test_field_comes_from_the_twin_scene():
    f = load_scene()  # core/scenes/field.toml
    assert (f.field.size_x_m, f.field.size_y_m) == (60.0, 37.0)
    assert {p.name: p.x_m for p in f.pads} == {"start": -20.0, "landing": 20.0}
    assert sorted(o.x_m for o in f.obstacles) == [-7.0, 7.0]
    assert all(o.height_m == 3.0 for o in f.obstacles)


def test_station_draws_a_field_file_and_survives_a_bad_one(tmp_path):
    scene = tmp_path / "field.toml"
    scene.write_text(
        "[home]\nlat_deg = 43.0\nlon_deg = -78.8\nalt_m = 200.0\n"
        "[field]\nsize_x_m = 30.0\nsize_y_m = 20.0\n"
        '[[pads]]\nname = "start"\nx_m = -10.0\ny_m = 0.0\n'
        '[[obstacles]]\nname = "pole a"\nx_m = 2.0\ny_m = 3.0\nheight_m = 5.0\n'
    )
    settings = load_settings(
        environ={},
        overrides={"link.source": "none", "viser.port": 0, "viser.field_file": str(scene)},
    )
    app = create_app(settings)
    with run_uvicorn(app) as base:
        assert httpx.get(f"{base}/api/viser").json()["enabled"]
        handles = app.state.station.trajectory3d.scene.field_handles
        assert set(handles) == {"pad:start", "obstacle:pole a"}
        assert np.allclose(handles["obstacle:pole a"].position, (2.0, 3.0, 2.5))
    settings = load_settings(
        environ={},
        overrides={
            "link.source": "none",
            "viser.port": 0,
            "viser.field_file": str(tmp_path / "nope.toml"),
        },
    )
    app = create_app(settings)
    with run_uvicorn(app) as base:  # no field, but the panel runs
        assert httpx.get(f"{base}/api/viser").json()["enabled"]
        assert app.state.station.trajectory3d.scene.field_handles == {}


def test_cli_serves_the_panel_on_its_port_and_stops_it(tmp_path):
    import signal

    from tests.helpers import free_port
    from tests.station_process import serve_station

    viser_port = free_port()
    args = ["--source", "none", "--viser-port", str(viser_port)]
    with serve_station(args, env={"FPV_RECORDING__SESSIONS_DIR": str(tmp_path)}) as station:
        panel = httpx.get(f"{station.base}/api/viser", timeout=30).json()  # the first visit
        assert panel["port"] == viser_port
        assert httpx.get(f"http://127.0.0.1:{viser_port}/", timeout=5).status_code == 200
        assert httpx.get(f"{station.base}{panel['path']}", timeout=5).status_code == 200
        station.popen.send_signal(signal.SIGINT)
        # uvicorn shuts down, then re-raises the SIGINT it caught: -2 is its clean exit
        assert station.popen.wait(timeout=20) in (0, -signal.SIGINT)
    with pytest.raises(httpx.ConnectError):
        httpx.get(f"http://127.0.0.1:{viser_port}/", timeout=2)


def test_positions_without_a_fix_are_not_drawn():
    from fpv_station.server.trajectory3d.service import sample_from_state

    good = make_state(1.0, (1.0, 2.0, 3.0))
    assert sample_from_state(good) is not None
    assert sample_from_state(make_state(1.0, (1.0, 2.0, 3.0), fix_type=2)) is None  # 2D fix
    zero = GlobalPosition(t_mono=1.0, lat_deg=0.0, lon_deg=0.0, alt_m=0.0)  # before a fix
    assert sample_from_state(VehicleState(global_position=zero)) is None
    nan = GlobalPosition(t_mono=1.0, lat_deg=float("nan"), lon_deg=1.0, alt_m=0.0)
    assert sample_from_state(VehicleState(global_position=nan)) is None
    # only the raw GPS: used when it has a 3D fix
    raw = make_state(1.0, (1.0, 2.0, 3.0)).gps
    s = sample_from_state(VehicleState(gps=raw))
    assert s is not None and s.lat_deg == raw.lat_deg


def test_the_scene_is_changed_only_on_vipers_own_loop_thread(monkeypatch):
    """viser wakes its senders with an asyncio.Event of its own loop, set from the thread
    that changes the scene: from any other thread that races its viewers' waits ("deque
    mutated during iteration"). Every message the panel queues, from its start, its
    steps, its GUI requests and its redraws, with many viewers watching a fast trail,
    must be queued on the loop of the buffer it goes into."""
    import fpv_station.server.trajectory3d.service as service_module

    foreign = watch_viser_pushes(monkeypatch, service_module)
    state: Latest[VehicleState] = Latest()
    svc = Trajectory3D(
        ViserSettings(port=0, chunk_segments=5, update_hz=30.0),
        state,
        host="127.0.0.1",
        field=FIELD,
    )
    svc.start()
    try:
        with contextlib.ExitStack() as viewers:
            for _ in range(12):
                viewers.enter_context(viser_viewer(svc.port))
            assert wait_until(lambda: len(svc.server.get_clients()) == 12)
            # Each viewer's camera moves too (set where a viewer's change lands).
            svc.controls.follow = True

            async def fly() -> None:
                task = asyncio.create_task(svc.run())
                for i in range(400):
                    state.publish(make_state(i * 0.05, (i * 0.1, 0.0, 3.0)))
                    if i == 200:
                        svc.controls._requests.color_by = "speed"  # a whole redraw
                    await asyncio.sleep(0.005)
                    assert not task.done(), task
                state.close()
                await asyncio.wait_for(task, 10.0)

            asyncio.run(fly())
        assert svc.steps > 20 and len(svc.scene.chunk_handles) > 2
        assert foreign == [], foreign[:5]
    finally:
        svc.stop()
