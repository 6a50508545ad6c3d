"""Draws the flight into a viser scene: field, home, vehicle, camera footprint, trail.

World frame: East-North-Up metres about the flight's origin (the arming point), +z up.
Every method sends only what changed: the vehicle moves by two small messages
(position, orientation), the footprint is four segments, and the trail sends only its
open chunk (see trail.py); frozen chunks are never resent unless the origin or the
colour-coding changes.
"""

from __future__ import annotations

import numpy as np
import viser
from numpy.typing import NDArray

from fpv_station.core.scene import Scene, bgr_to_rgb
from fpv_station.server.trajectory3d.colors import ColorBy, ramp_rgb
from fpv_station.server.trajectory3d.pose import wxyz as as_wxyz
from fpv_station.server.trajectory3d.pose import xyz
from fpv_station.server.trajectory3d.trail import Origin, Trail, TrailChunk

# The F450 drawn three times its size, so that it stays visible over a 60 m field.
_BODY_SCALE = 3.0
_ARM_M = 0.45
_FOOTPRINT_RGB = (250, 120, 200)


class LiveScene:
    """The scene objects of one viser server and the trail handles they map to."""

    def __init__(
        self,
        server: viser.ViserServer,
        *,
        height_range_m: tuple[float, float],
        speed_range_mps: tuple[float, float],
        color_by: ColorBy = "height",
        field: Scene | None = None,
    ) -> None:
        self.server = server
        self.scene = server.scene
        self.height_range_m = height_range_m
        self.speed_range_mps = speed_range_mps
        self.color_by: ColorBy = color_by
        self.field = field
        self.chunk_handles: dict[int, viser.LineSegmentsHandle] = {}
        self.field_handles: dict[str, viser.SceneNodeHandle] = {}
        self._footprint: viser.LineSegmentsHandle | None = None
        self._field_frame = self._add_field(field)
        self._home = self.scene.add_icosphere(
            "/home", radius=0.25, color=(255, 200, 0), position=(0.0, 0.0, 0.0)
        )
        self.scene.add_label("/home/label", "home", position=(0.0, 0.0, 0.6))
        self.vehicle = self._add_vehicle()

    # -- static parts -------------------------------------------------------------

    def _add_field(self, f: Scene | None) -> viser.FrameHandle:
        frame = self.scene.add_frame("/field", show_axes=False)
        if f is None:
            self.scene.add_grid(
                "/field/grid", width=100.0, height=100.0, cell_size=1.0, section_size=10.0
            )
            return frame
        self.scene.add_grid(
            "/field/grid",
            width=f.field.size_x_m,
            height=f.field.size_y_m,
            cell_size=1.0,
            section_size=5.0,
            plane_color=(215, 235, 205),
            plane_opacity=0.6,
        )
        for pad in f.pads:
            self.field_handles[f"pad:{pad.name}"] = self.scene.add_box(
                f"/field/pads/{_node(pad.name)}",
                color=bgr_to_rgb(pad.bgr),
                dimensions=(pad.size_m, pad.size_m, 0.04),
                position=(pad.x_m, pad.y_m, 0.02),
            )
        for ob in f.obstacles:
            self.field_handles[f"obstacle:{ob.name}"] = self.scene.add_box(
                f"/field/obstacles/{_node(ob.name)}",
                color=bgr_to_rgb(ob.bgr),
                dimensions=(ob.width_m, ob.depth_m, ob.height_m),
                position=(ob.x_m, ob.y_m, ob.height_m / 2.0),
            )
        return frame

    def _add_vehicle(self) -> viser.FrameHandle:
        body = self.scene.add_frame("/vehicle", axes_length=0.5, axes_radius=0.03)
        s = _BODY_SCALE
        for i, angle in enumerate((np.pi / 4, -np.pi / 4)):
            wxyz = (np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2))
            self.scene.add_box(
                f"/vehicle/arm{i}",
                color=(60, 60, 60),
                dimensions=(_ARM_M * s, 0.03 * s, 0.02 * s),
                wxyz=wxyz,
            )
        # The nose marks forward (+x of the body, FLU), as the front camera looks.
        self.scene.add_box(
            "/vehicle/nose",
            color=(230, 30, 30),
            dimensions=(0.12 * s, 0.06 * s, 0.04 * s),
            position=(0.12 * s, 0.0, 0.0),
        )
        return body

    def set_origin(self, origin: Origin) -> None:
        """Place the field for a new ENU origin (the home marker stays at 0, 0, 0)."""
        if self.field is not None:
            self._field_frame.position = tuple(self.field.origin_in_enu(origin))

    def set_field_visible(self, visible: bool) -> None:
        self._field_frame.visible = visible

    # -- moving parts -------------------------------------------------------------

    def set_vehicle_pose(
        self, position_enu_m: NDArray[np.float64], wxyz: NDArray[np.float64]
    ) -> None:
        self.vehicle.position = xyz(position_enu_m)
        self.vehicle.wxyz = as_wxyz(wxyz)

    def set_footprint(self, corners_enu_m: NDArray[np.float64] | None) -> None:
        if corners_enu_m is None:
            if self._footprint is not None and self._footprint.visible:
                self._footprint.visible = False
            return
        lifted = np.asarray(corners_enu_m, np.float32) + np.array([0, 0, 0.03], np.float32)
        pts = np.stack([lifted, np.roll(lifted, -1, axis=0)], axis=1)
        if self._footprint is None:
            self._footprint = self.scene.add_line_segments(
                "/footprint",
                points=pts,
                colors=_FOOTPRINT_RGB,
                thickness=2.0,
                thickness_units="screen",
            )
        else:
            self._footprint.points = pts
            if not self._footprint.visible:
                self._footprint.visible = True

    # -- the trail ----------------------------------------------------------------

    def _chunk_colors(self, heights: NDArray, speeds: NDArray) -> NDArray[np.uint8]:
        if self.color_by == "speed":
            return ramp_rgb(speeds, *self.speed_range_mps)
        return ramp_rgb(heights, *self.height_range_m)

    def sync_chunk(self, chunk: TrailChunk) -> None:
        """Send one chunk: created on its first segment, updated in place afterwards."""
        pts, heights, speeds = chunk.segments()
        if len(pts) == 0:
            return
        colors = self._chunk_colors(heights, speeds)
        handle = self.chunk_handles.get(chunk.id)
        if handle is None:
            self.chunk_handles[chunk.id] = self.scene.add_line_segments(
                f"/trail/c{chunk.id:06d}",
                points=pts,
                colors=colors,
                thickness=4.0,
                thickness_units="screen",
            )
        else:
            handle.points = pts
            handle.colors = colors

    def drop_chunks(self, chunks: list[TrailChunk]) -> None:
        for chunk in chunks:
            handle = self.chunk_handles.pop(chunk.id, None)
            if handle is not None:
                handle.remove()

    def forget_dropped(self, trail: Trail) -> None:
        """Remove the handles of chunks the trail no longer holds (before a redraw: the
        service resends the others a few at a time, Trajectory3D._redraw_turns)."""
        kept = {chunk.id for chunk in trail.chunks}
        for chunk_id in [i for i in self.chunk_handles if i not in kept]:
            self.chunk_handles.pop(chunk_id).remove()


def _node(name: str) -> str:
    """A scene-tree-safe node name ("obstacle 1" -> "obstacle_1"; no "/" nesting)."""
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name) or "unnamed"
