"""The 3D panel's service: a viser server on its own port, fed from the vehicle state.

`run()` awaits newer states from the station's `Latest[VehicleState]` and applies at most
`update_hz` of them per second (the newest wins; a 50 Hz GLOBAL_POSITION_INT stream costs
no more than a 10 Hz one). `step()` is the whole per-update work and is synchronous, so
tests drive it directly with a sequence of states.

The scene is drawn only while someone has the panel open: until then a step only extends
the trail (the flight's history), and the first viewer gets the whole trail drawn at once.
A panel nobody looks at costs a fraction of one drawn (docs/PERFORMANCE.md): the states
for its trail are kept by a listener on the state slot (the link's thread, `update_hz` a
second), and the event loop takes them once a second, or as soon as a viewer comes,
instead of waking `update_hz` times a second for them. The viser
server itself (and viser's import) waits for `start()`, which the station calls on the
first visit (server.station.start_3d_panels); the trail is kept from the station's start.

Once viser runs, `run()` hands each update (one step, one batch of kept states, one turn
of a redraw) to viser's own event-loop thread and awaits it there (viser_loop.py): viser's
scene and GUI are changed on no other thread.
"""

from __future__ import annotations

import asyncio
import collections
import functools
import logging
import math
import time
from collections.abc import Callable, Iterator, Mapping
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from fpv_station.companion.latest import Latest, Wakeup
from fpv_station.companion.vehicle_state import VehicleState
from fpv_station.core.geodesy import geodetic_to_enu
from fpv_station.core.scene import Scene
from fpv_station.server.settings import ViserSettings
from fpv_station.server.trajectory3d.gate import LOOPBACK, PilotPath, ViewerInput, open_viser
from fpv_station.server.trajectory3d.pose import (
    R_enu_flu_from_euler,
    bottom_footprint_enu,
    wxyz_from_matrix,
)
from fpv_station.server.trajectory3d.trail import Origin, Trail, TrailSample
from fpv_station.server.trajectory3d.viser_loop import on_viser_loop, on_viser_loop_blocking

if TYPE_CHECKING:  # imported by start(): viser costs memory and start-up time
    import viser

    from fpv_station.server.trajectory3d.controls import Controls
    from fpv_station.server.trajectory3d.live_scene import LiveScene

log = logging.getLogger(__name__)
T = TypeVar("T")
_DONE = object()

MIN_FIX_TYPE = 3  # a 2D fix has no usable altitude: drawn as a gap
# Chunks resent per turn of the event loop when the whole trail is redrawn (a first viewer,
# a new origin, another colour-coding): viser builds a chunk's handle in a few ms (more on
# a Pi), and a long flight's trail sent at once held the station's loop for seconds.
REDRAW_CHUNKS_PER_TURN = 8
# While nobody watches, the loop takes the kept states this often (or when a viewer comes).
UNWATCHED_TURN_S = 1.0
# The states kept for an unwatched trail: 10 s of them at most (a loop held up longer
# loses the oldest, not memory).
KEPT_S = 10.0


def _valid_fix(
    lat_deg: float | None, lon_deg: float | None, alt_m: float | None
) -> tuple[float, float, float] | None:
    """(lat, lon, alt) when the coordinates are worth drawing: present, finite, on the
    globe, and not the (0, 0) that autopilots send before their first fix; else None."""
    if lat_deg is None or lon_deg is None or alt_m is None:
        return None
    if not all(math.isfinite(v) for v in (lat_deg, lon_deg, alt_m)):
        return None
    if abs(lat_deg) <= 90 and abs(lon_deg) <= 180 and (lat_deg, lon_deg) != (0.0, 0.0):
        return lat_deg, lon_deg, alt_m
    return None


def sample_from_state(state: VehicleState) -> TrailSample | None:
    """The position to draw: the autopilot's fused GLOBAL_POSITION_INT, else the raw GPS.
    None when there is no 3D fix (the trail then shows a gap)."""
    gps, gp = state.gps, state.global_position
    if gps.t_mono is not None and gps.fix_type < MIN_FIX_TYPE:
        return None
    if gp.t_mono is not None and (fix := _valid_fix(gp.lat_deg, gp.lon_deg, gp.alt_m)):
        speed = (
            math.hypot(gp.vx_mps, gp.vy_mps)
            if gp.vx_mps is not None and gp.vy_mps is not None
            else math.nan
        )
        return TrailSample(gp.t_mono, *fix, speed)
    if gps.t_mono is not None and (fix := _valid_fix(gps.lat_deg, gps.lon_deg, gps.alt_m)):
        speed = gps.ground_speed_mps if gps.ground_speed_mps is not None else math.nan
        return TrailSample(gps.t_mono, *fix, speed)
    return None


def origin_from_state(state: VehicleState) -> Origin | None:
    """The arming point (or the first fix before any arming), as the link measured it."""
    a = state.altitude
    if a.reference == "none":
        return None
    return _valid_fix(a.home_lat_deg, a.home_lon_deg, a.reference_alt_m)


class Trajectory3D:
    """Owns the viser server, the live scene and the trail."""

    def __init__(
        self,
        settings: ViserSettings,
        state: Latest[VehicleState],
        host: str = LOOPBACK,
        field: Scene | None = None,
    ) -> None:
        self.settings = settings
        self.state = state
        self.host = host  # loopback: viewers come through the relay (gate.py)
        self.field = field
        self.trail = Trail(
            settings.chunk_segments, settings.gap_s, settings.max_points, settings.trail_min_step_m
        )
        self.pilot_path = PilotPath()
        self.server: viser.ViserServer | None = None
        self.scene: LiveScene | None = None
        self.controls: Controls | None = None
        self.steps = 0
        self._last_sample_t: float | None = None
        self._status_due = 0.0
        self._ground_for: Origin | None = None
        self._ground_up = 0.0
        self._stale = True  # the scene lags the trail: redraw it whole (for the next viewer)
        # The states of the trail while nobody watches: appended by `_keep` (the link's
        # thread), taken by `run()` (the loop); a deque's append and popleft are atomic.
        self._kept: collections.deque[VehicleState] = collections.deque(
            maxlen=int(KEPT_S * settings.update_hz)
        )
        self._next_keep = 0.0
        self._viewer_came = Wakeup()  # viser's connect callback wakes an unwatched wait

    # -- lifecycle ----------------------------------------------------------------

    def start(self) -> None:
        """Start the viser server (its own thread and event loop). Blocks briefly; may run
        in a worker thread while `run()` steps: `server` is set last, once all is built."""
        from fpv_station.server.trajectory3d.controls import Controls
        from fpv_station.server.trajectory3d.live_scene import LiveScene

        s = self.settings
        server = open_viser(s.port, "fpv-station 3D", self.host)

        def build() -> tuple[LiveScene, Controls]:  # on viser's loop, as every change
            server.gui.configure_theme(show_share_button=False)
            server.scene.set_up_direction("+z")
            server.initial_camera.position = (-25.0, -30.0, 20.0)
            server.initial_camera.look_at = (0.0, 0.0, 0.0)
            scene = LiveScene(
                server,
                height_range_m=s.height_range_m,
                speed_range_mps=s.speed_range_mps,
                color_by=s.color_by,
                field=self.field,
            )
            if self.field is not None:
                # Before any fix, show the field about its own anchor.
                scene.set_origin(self.field.home_llh)
            return scene, Controls(server, s.color_by)

        self.scene, self.controls = on_viser_loop_blocking(server, build)
        self._stale = True
        controls = self.controls

        @server.on_client_connect
        def _(client: viser.ClientHandle) -> None:  # on viser's loop
            if self.pilot_path.marks(server, client):
                controls.add_pilot(client)
            self._viewer_came.wake()

        server.on_client_disconnect(controls.remove_pilot)
        self.server = server
        log.info("3D panel (viser) on port %d", self.port)

    @property
    def port(self) -> int:
        if self.server is None:
            raise RuntimeError("The 3D panel is not started.")
        return self.server.get_port()

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()
            self.server = None

    def viewer_inputs(self) -> Mapping[str, ViewerInput]:
        """The GUI inputs viewers may change (server/trajectory3d/gate.py), by uuid."""
        return self.controls.inputs() if self.controls is not None else {}

    def upstream_path(self, authorized: bool) -> str:
        """Where the relay opens a viewer's connection to viser: a viewer with the
        token gets the controls (controls.py), any other watches."""
        return self.pilot_path.upstream(authorized)

    async def run(self) -> None:
        """Apply the states to the trail, `update_hz` of them a second, until the slot
        closes: while someone watches, the newest one each 1 / `update_hz` s, drawn; while
        nobody does, the ones `_keep` kept, once a second or as soon as a viewer comes."""
        self.state.add_listener(self._keep)
        try:
            await self._run()
        finally:
            self.state.remove_listener(self._keep)

    def _keep(self, state: VehicleState) -> None:
        """The state slot's listener (the link's thread): one state per 1 / `update_hz` s."""
        now = time.monotonic()
        if now >= self._next_keep:
            self._next_keep = now + 1.0 / self.settings.update_hz
            self._kept.append(state)

    async def _take_kept_until_watched(self) -> None:
        """Nobody watches: wait a second, or until a viewer comes, then bring the trail up
        to the states kept meanwhile, in their order."""
        self._viewer_came.clear()
        if not self.watched():  # one may have come before the clear
            await self._viewer_came.wait(UNWATCHED_TURN_S)
        if self._kept:
            await self._on_viser(self._step_kept)

    def _step_kept(self) -> None:
        while self._kept:
            self.step(self._kept.popleft(), draw=False)

    async def _on_viser(self, fn: Callable[[], T]) -> T:
        """Run `fn` (a step: it may change the scene) on viser's loop thread once the
        server runs (viser_loop.py); before that there is no scene, and it runs here."""
        server = self.server
        if server is None:
            return fn()
        return await on_viser_loop(server, fn)

    async def _run(self) -> None:
        period_s = 1.0 / self.settings.update_hz
        version = 0
        next_step = time.monotonic()
        while not self.state.closed:
            if not self.watched():
                await self._take_kept_until_watched()
                continue
            self._kept.clear()  # drawn from the newest state below while watched
            delay = next_step - time.monotonic()
            if delay > 0:
                await asyncio.sleep(delay)
            current = await self.state.wait_newer(version, timeout=0.25)
            if current is not None and current.version > version:
                version = current.version
                await self._on_viser(functools.partial(self.step, current.value, redraw=False))
                next_step = time.monotonic() + period_s
            else:
                await self._on_viser(self.apply_requests)  # GUI actions, no telemetry
            if self._stale and self.watched():  # a viewer came, or the step asked for it
                # One turn per hop: both loops serve the others between turns.
                turns = self._redraw_turns(REDRAW_CHUNKS_PER_TURN)
                while await self._on_viser(functools.partial(next, turns, _DONE)) is not _DONE:
                    pass

    # -- one update ----------------------------------------------------------------

    def apply_requests(self) -> None:
        if self.server is None or self.scene is None or self.controls is None:
            return  # not started: nobody could ask for anything
        req = self.controls.take_requests()
        if req.field_visible is not None:
            self.scene.set_field_visible(req.field_visible)
        if req.clear:
            self.scene.drop_chunks(self.trail.clear())
        if req.color_by is not None and req.color_by != self.scene.color_by:
            self.scene.color_by = req.color_by
            self._stale = True  # every chunk's colours

    def watched(self) -> bool:
        """Whether anyone has the panel open (a viser client is connected)."""
        return self.server is not None and bool(self.server.get_clients())

    def step(self, state: VehicleState, redraw: bool = True, draw: bool = True) -> None:
        """Bring the trail up to `state`, and while someone watches the scene too: origin,
        trail, vehicle, footprint, camera. A whole redraw the update calls for (a first
        viewer, a new origin, another colour-coding) is done here, or with `redraw` False
        left to the caller: run() does it a few chunks per turn of the loop. `draw` False
        leaves the scene to that whole redraw (states taken late, a batch at a time)."""
        self.steps += 1
        if not draw or self.server is None or not self.watched():
            self._stale = True
            self._step(state, scene=None)
            return
        # One atomic batch per update: viewers apply it as a whole, and viser wakes its
        # sender once per step instead of once per message.
        with self.server.atomic():
            self._step(state, self.scene)
            if self._stale and redraw:
                for _ in self._redraw_turns(max(len(self.trail.chunks), 1)):
                    pass

    def _redraw_turns(self, chunks_per_turn: int) -> Iterator[None]:
        """Redraw the trail whole: the origin, then the chunks, newest first (the flight
        now shows at once), `chunks_per_turn` of them per atomic batch; yields after each."""
        assert self.server is not None and self.scene is not None
        self._stale = False
        chunks = self.trail.chunks[::-1]
        with self.server.atomic():
            if self.trail.origin is not None:
                self.scene.set_origin(self.trail.origin)
            self.scene.forget_dropped(self.trail)
        for i in range(0, len(chunks), chunks_per_turn):
            with self.server.atomic():
                for chunk in chunks[i : i + chunks_per_turn]:
                    self.scene.sync_chunk(chunk)
            yield

    def _step(self, state: VehicleState, scene: LiveScene | None) -> None:
        """Extend the trail with `state`; draw it on `scene` too (None: the trail only)."""
        self.apply_requests()
        origin = origin_from_state(state)
        if origin is not None and self.trail.set_origin(origin) and scene is not None:
            scene.set_origin(origin)
            self._stale = True  # every chunk re-projected
        sample = sample_from_state(state)
        if sample is None:
            self.trail.mark_gap()
            if scene is not None:
                scene.set_footprint(None)
                self._status(state, "no position fix: the trail pauses")
            return
        if self._last_sample_t is None or sample.t_s > self._last_sample_t:
            self._last_sample_t = sample.t_s
            new_origin = self.trail.origin is None
            changed, dropped = self.trail.append(sample)
            if scene is not None:
                if new_origin and self.trail.origin is not None:
                    scene.set_origin(self.trail.origin)
                scene.drop_chunks(dropped)
                for chunk in changed:
                    scene.sync_chunk(chunk)
        if scene is None:
            return
        assert self.controls is not None
        assert self.trail.origin is not None
        pos = self.trail.last_enu_m if self.trail.held is None else None
        if pos is None:  # a sample held (not a point), or the trail cleared since this fix
            pos = geodetic_to_enu(sample.lat_deg, sample.lon_deg, sample.alt_m, *self.trail.origin)
        R = self._attitude(state)
        scene.set_vehicle_pose(pos, wxyz_from_matrix(R))
        s = self.settings
        scene.set_footprint(
            bottom_footprint_enu(
                pos,
                R,
                math.radians(s.bottom_hfov_deg),
                math.radians(s.bottom_vfov_deg),
                ground_up_m=self._ground_up_m(),
            )
        )
        if self.controls.follow:
            self._follow(pos)
        self._status(
            state,
            f"{self.trail.n_points} points, {len(scene.chunk_handles)} "
            f"chunks; height {pos[2]:.1f} m",
        )

    def _attitude(self, state: VehicleState) -> np.ndarray:
        a = state.attitude
        if a.roll_rad is not None and a.pitch_rad is not None and a.yaw_rad is not None:
            return R_enu_flu_from_euler(a.roll_rad, a.pitch_rad, a.yaw_rad)
        heading = state.global_position.heading_deg
        return R_enu_flu_from_euler(0.0, 0.0, math.radians(heading or 0.0))

    def _ground_up_m(self) -> float:
        """The ground's height in the flight frame: the field's if known, else the origin's."""
        if self.field is None or self.trail.origin is None:
            return 0.0
        if self._ground_for != self.trail.origin:
            self._ground_for = self.trail.origin
            self._ground_up = float(self.field.origin_in_enu(self.trail.origin)[2])
        return self._ground_up

    def _follow(self, pos: np.ndarray) -> None:
        """Keep each viewer's camera offset, moved along with the vehicle."""
        assert self.server is not None
        for client in self.server.get_clients().values():
            cam = client.camera
            # viser's position setter moves look_at along by the same offset, so one
            # assignment translates the whole view onto the vehicle.
            cam.position = np.asarray(cam.position) + (pos - np.asarray(cam.look_at))

    def _status(self, state: VehicleState, text: str) -> None:
        now = time.monotonic()
        if now >= self._status_due and self.controls is not None:
            self._status_due = now + 1.0  # a readout for people: once a second is plenty
            self.controls.set_status(text)
