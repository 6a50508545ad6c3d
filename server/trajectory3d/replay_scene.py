"""The replay in 3D: a second viser server whose scene shows recorded sessions.

It reuses the live scene (scene.py: field, home, vehicle body, footprint, colour-coded
trail chunks) on its own port, so that the replay never disturbs the live panel. `load()`
draws the whole path of a session (built by replay.py's `build_trajectory`, gaps as gaps)
and an optional overlay session in one colour; `set_time()` moves the vehicle and the
bottom camera's footprint to an instant of the session clock (the rows' and frames'
`t_s`, as the replay page's slider). The scene is shared by every viewer of the
replay panel: whoever loads or scrubs last wins (a field station has few users).

Attitude is not in the trajectory reply: the body is drawn level, its nose along the
direction of travel (the last horizontal motion of more than 5 cm).
"""

from __future__ import annotations

import logging
import math
import threading

import numpy as np
import viser

from fpv_station.core.scene import Scene
from fpv_station.server.settings import ViserSettings
from fpv_station.server.trajectory3d.gate import LOOPBACK, ViewerInput, gui_uuid, open_viser
from fpv_station.server.trajectory3d.live_scene import LiveScene
from fpv_station.server.trajectory3d.pose import (
    R_enu_flu_from_euler,
    bottom_footprint_enu,
    wxyz_from_matrix,
    xyz,
)
from fpv_station.server.trajectory3d.replay import TrajectoryReply
from fpv_station.server.trajectory3d.trail import TrailChunk
from fpv_station.server.trajectory3d.viser_loop import on_viser_loop_blocking

log = logging.getLogger(__name__)

OVERLAY_RGB = (150, 60, 200)  # purple, as the 2D replay page draws the compared session
_CHUNK_SEGMENTS = 500  # one scene handle per 500 segments: few messages, bounded size


class ReplayPath:
    """One session as numpy arrays, its times on the session clock (as the rows and
    frames: one time axis for every view of the session)."""

    def __init__(self, reply: TrajectoryReply) -> None:
        self.id = reply.id
        self.t_s = np.asarray(reply.t_s, float)
        self.enu_m = np.column_stack([reply.x_m, reply.y_m, reply.z_m]).astype(float)
        self.speed_mps = np.array([np.nan if v is None else v for v in reply.speed_mps], float)
        self.starts_run = np.asarray(reply.starts_run, bool)
        self.origin = (reply.origin.lat_deg, reply.origin.lon_deg, reply.origin.alt_m or 0.0)
        self.align_rad = reply.align_rad
        self.yaw_enu_rad = _travel_heading_rad(self.enu_m)
        self.duration_s = max(float(reply.duration_s), float(self.t_s[-1]))

    def index_at(self, t_s: float) -> int:
        """The last fix at or before `t_s` (session clock); -1 before the first fix."""
        return int(np.searchsorted(self.t_s, t_s, side="right")) - 1

    def chunks(self) -> list[TrailChunk]:
        """The path as trail chunks for LiveScene.sync_chunk; continuous across chunks."""
        out: list[TrailChunk] = []
        n = len(self.t_s)
        for k, start in enumerate(range(0, max(n - 1, 1), _CHUNK_SEGMENTS)):
            stop = min(start + _CHUNK_SEGMENTS + 1, n)
            runs = self.starts_run[start:stop].copy()
            runs[0] = True  # a chunk's first point joins nothing before it
            out.append(
                TrailChunk.from_enu(k, self.enu_m[start:stop], self.speed_mps[start:stop], runs)
            )
        return out


def _travel_heading_rad(enu_m: np.ndarray) -> np.ndarray:
    """ENU heading (from +x, counter-clockwise) of the last horizontal step > 5 cm."""
    d = np.diff(enu_m[:, :2], axis=0, prepend=enu_m[:1, :2])
    moved = np.hypot(d[:, 0], d[:, 1]) > 0.05
    idx = np.where(moved, np.arange(len(d)), -1)
    last = np.maximum.accumulate(idx)
    yaw = np.arctan2(d[np.maximum(last, 0), 1], d[np.maximum(last, 0), 0])
    return np.where(last >= 0, yaw, 0.0)


class Replay3D:
    """Owns the replay viser server and its scene; thread-safe load and set_time."""

    def __init__(
        self, settings: ViserSettings, host: str = LOOPBACK, field: Scene | None = None
    ) -> None:
        self.settings = settings
        self.host = host  # loopback: viewers come through the relay (gate.py)
        self.field = field
        self.server: viser.ViserServer | None = None
        self.scene: LiveScene | None = None
        self.primary: ReplayPath | None = None
        self.overlay: ReplayPath | None = None
        self.overlay_handles: list[viser.SceneNodeHandle] = []
        self.overlay_vehicle: viser.IcosphereHandle | None = None
        self.t_s = 0.0
        self._framing: tuple[tuple[float, ...], tuple[float, ...]] | None = None  # look, eye
        self._title: viser.GuiMarkdownHandle | None = None
        self._inputs: dict[str, ViewerInput] = {}
        self._lock = threading.Lock()  # a load and a set_time called from other threads

    def start(self) -> None:
        s = self.settings
        server = open_viser(s.replay_port_resolved, "fpv-station replay 3D", self.host)
        self.server = server

        def build() -> LiveScene:  # on viser's loop, as every change (viser_loop.py)
            server.scene.set_up_direction("+z")
            server.initial_camera.position = (-25.0, -30.0, 20.0)
            server.initial_camera.look_at = (0.0, 0.0, 0.0)
            self._add_gui()
            return LiveScene(
                server,
                height_range_m=s.height_range_m,
                speed_range_mps=s.speed_range_mps,
                color_by=s.color_by,
                field=self.field,
            )

        self.scene = on_viser_loop_blocking(server, build)
        log.info("3D replay panel (viser) on port %d", self.port)

    def _add_gui(self) -> None:
        """A user's panel, not a developer's: viser shows its own controls (Save Canvas,
        Reset View, the scene tree) only while a server has no GUI of its own, so the
        panel carries what a user wants instead: which session, and the path framed."""
        assert self.server is not None
        gui = self.server.gui
        gui.configure_theme(show_logo=False, show_share_button=False, control_width="small")
        self._title = gui.add_markdown("No session loaded")
        frame = gui.add_button("Frame the path", hint="Look at the whole path again")
        # It moves the clicking viewer's camera only: anyone may use it.
        self._inputs = {gui_uuid(frame): ViewerInput(bool, personal=True)}

        @frame.on_click
        def _(event: viser.GuiEvent) -> None:
            # viser calls this on its worker pool: the camera moves on viser's loop.
            client, framing = event.client, self._framing
            if client is not None and framing is not None and self.server is not None:
                on_viser_loop_blocking(self.server, lambda: self._move_camera(client, *framing))

    def viewer_inputs(self) -> dict[str, ViewerInput]:
        """The GUI inputs viewers may change (server/trajectory3d/gate.py), by uuid."""
        return self._inputs

    def upstream_path(self, authorized: bool) -> str:
        """Where the relay opens a viewer's connection: the replay's one input is
        every viewer's own, so every viewer alike."""
        return "/"

    @property
    def port(self) -> int:
        if self.server is None:
            raise RuntimeError("The 3D replay panel is not started.")
        return self.server.get_port()

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()
            self.server = None

    def load(self, primary: TrajectoryReply, overlay: TrajectoryReply | None = None) -> None:
        """Replace the drawn sessions (heavy; on viser's loop, `viser_loop.on_viser_loop`)."""
        assert self.server is not None and self.scene is not None
        a = ReplayPath(primary)
        b = ReplayPath(overlay) if overlay is not None else None
        with self._lock, self.server.atomic():
            sc = self.scene
            for h in list(sc.chunk_handles.values()):
                h.remove()
            sc.chunk_handles.clear()
            for node in reversed(self.overlay_handles):  # children (the label) first
                node.remove()
            self.overlay_handles = []
            self.overlay_vehicle = None
            self._place_field(a)
            for chunk in a.chunks():
                sc.sync_chunk(chunk)
            if b is not None:
                self._draw_overlay(b)
            self.primary, self.overlay = a, b
            self._set_time(0.0)  # the session's start, where the replay page starts
            if self._title is not None:
                also = f" with **{b.id}**" if b is not None else ""
                self._title.content = f"**{a.id}**{also}, {a.duration_s:.0f} s"
            self._frame_camera(np.concatenate([a.enu_m] + ([b.enu_m] if b else [])))

    def _frame_camera(self, pts_enu_m: np.ndarray) -> None:
        """Look at the whole path from the south-west, above: new viewers and open ones."""
        assert self.server is not None
        lo, hi = pts_enu_m.min(axis=0), pts_enu_m.max(axis=0)
        centre = (lo + hi) / 2.0
        span = max(float(np.linalg.norm(hi - lo)), 10.0)
        eye = centre + np.array([-0.45, -0.65, 0.6]) * span
        look, pos = xyz(centre), xyz(eye)
        # New viewers start from initial_camera (and viser's own "Reset View" goes back to
        # it); open ones are moved.
        self.server.initial_camera.look_at = look
        self.server.initial_camera.position = pos
        self._framing = (look, pos)
        for client in self.server.get_clients().values():
            self._move_camera(client, look, pos)

    @staticmethod
    def _move_camera(client: viser.ClientHandle, look: tuple, pos: tuple) -> None:
        # The position setter drags look_at along: set look_at second. A client that has
        # not reported its camera yet fails viser's assert and gets initial_camera.
        try:
            client.camera.position = pos
            client.camera.look_at = look
        except AssertionError:
            pass

    def _place_field(self, a: ReplayPath) -> None:
        """The field in the session's (possibly aligned) ENU frame."""
        assert self.scene is not None
        if self.field is None:
            return
        anchor = self.field.origin_in_enu(a.origin)
        c, s = math.cos(a.align_rad), math.sin(a.align_rad)
        frame = self.scene._field_frame
        frame.position = (c * anchor[0] - s * anchor[1], s * anchor[0] + c * anchor[1], anchor[2])
        frame.wxyz = (math.cos(a.align_rad / 2), 0.0, 0.0, math.sin(a.align_rad / 2))

    def _draw_overlay(self, b: ReplayPath) -> None:
        assert self.server is not None
        joined = np.nonzero(~b.starts_run[1:])[0] + 1
        if len(joined):
            pts = np.stack([b.enu_m[joined - 1], b.enu_m[joined]], axis=1).astype(np.float32)
            self.overlay_handles.append(
                self.server.scene.add_line_segments(
                    "/overlay/path",
                    points=pts,
                    colors=OVERLAY_RGB,
                    thickness=3.0,
                    thickness_units="screen",
                )
            )
        self.overlay_vehicle = self.server.scene.add_icosphere(
            "/overlay/vehicle",
            radius=0.35,
            color=OVERLAY_RGB,
            position=xyz(b.enu_m[0]),
        )
        self.overlay_handles.append(self.overlay_vehicle)
        self.overlay_handles.append(
            self.server.scene.add_label("/overlay/vehicle/label", b.id, position=(0.0, 0.0, 0.7))
        )

    def set_time(self, t_s: float) -> float:
        """Move the vehicle(s) to the instant `t_s` of the primary's session clock (cheap:
        a few small messages). Returns the time applied (clamped to the session)."""
        # Never wait for a load in progress (this runs on a loop): that load ends
        # by setting its own time, and the page sends the next instant soon after.
        if not self._lock.acquire(blocking=False):
            return self.t_s
        try:
            if self.server is None or self.primary is None:
                return 0.0
            with self.server.atomic():
                return self._set_time(t_s)
        finally:
            self._lock.release()

    def _set_time(self, t_s: float) -> float:
        assert self.scene is not None and self.primary is not None
        a = self.primary
        t = min(max(float(t_s), 0.0), a.duration_s) if math.isfinite(t_s) else 0.0
        self.t_s = t
        i = a.index_at(t)
        vehicle = self.scene.vehicle
        if vehicle.visible != (i >= 0):  # before the first fix nobody knew where it was
            vehicle.visible = i >= 0
        if i < 0:
            self.scene.set_footprint(None)
        else:
            self._place_vehicle(a, i)
        if self.overlay is not None and self.overlay_vehicle is not None:
            b = self.overlay
            j = b.index_at(t)
            if self.overlay_vehicle.visible != (j >= 0):
                self.overlay_vehicle.visible = j >= 0
            self.overlay_vehicle.position = xyz(b.enu_m[max(j, 0)])
        return t

    def _place_vehicle(self, a: ReplayPath, i: int) -> None:
        assert self.scene is not None
        pos = a.enu_m[i]
        # The body's yaw in the (possibly aligned) frame: NED yaw = pi/2 - ENU heading.
        R = R_enu_flu_from_euler(0.0, 0.0, math.pi / 2 - float(a.yaw_enu_rad[i]))
        self.scene.set_vehicle_pose(pos, wxyz_from_matrix(R))
        s = self.settings
        ground_up = 0.0
        if self.field is not None:
            ground_up = float(self.field.origin_in_enu(a.origin)[2])
        self.scene.set_footprint(
            bottom_footprint_enu(
                pos,
                R,
                math.radians(s.bottom_hfov_deg),
                math.radians(s.bottom_vfov_deg),
                ground_up_m=ground_up,
            )
        )
