"""The paper's figures, readable in print: 3D trajectory of all flights, bird's-eye view
with the field's pads and obstacles, and position history (x, y, z against time) per
flight with its analysis window shaded.

Figures are built on `matplotlib.figure.Figure` with the Agg canvas, never pyplot: pyplot
keeps global state, and the REST routes render in worker threads. Every figure has a
fixed size in pixels (`SIZE_PX`), so pages and papers can lay them out. matplotlib is
imported by the first figure, not with this module: the station serves without it until
someone asks for a plot (about 30 MB and half a second on a Pi).
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fpv_station.analysis.field_layout import FieldLayout, Obstacle
from fpv_station.analysis.flight_frame import AlignedTrack
from fpv_station.analysis.tasks import TASK_TITLES, TaskResult

if TYPE_CHECKING:
    from matplotlib.figure import Figure

PLOTS = ("trajectory3d", "birdseye", "history")
DPI = 150
FIGSIZE_IN = (8.0, 6.0)
SIZE_PX = (int(FIGSIZE_IN[0] * DPI), int(FIGSIZE_IN[1] * DPI))  # (width, height)
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf")


def _new_figure() -> Figure:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)  # no bbox_inches: keep the size fixed
    return buf.getvalue()


def _name(a: AlignedTrack, r: TaskResult) -> str:
    kind = {"physical": "physical", "twin": "twin"}.get(r.platform, r.platform)
    return f"{a.label} ({kind})"


def _field(aligned: Sequence[AlignedTrack]) -> FieldLayout | None:
    return next((a.field for a in aligned if a.field is not None), None)


def _obstacle_corners(o: Obstacle) -> np.ndarray:
    hw, hd = o.width_m / 2, o.depth_m / 2
    c, s = np.cos(o.yaw_rad), np.sin(o.yaw_rad)
    local = np.array([[-hw, -hd], [hw, -hd], [hw, hd], [-hw, hd]])
    return local @ np.array([[c, s], [-s, c]]) + [o.x_m, o.y_m]


def trajectory_3d(aligned: Sequence[AlignedTrack], results: Sequence[TaskResult]) -> bytes:
    fig = _new_figure()
    ax = fig.add_subplot(projection="3d")
    field = _field(aligned)
    if field is not None:
        for o in field.obstacles:
            xy = _obstacle_corners(o)
            for z in (0.0, o.height_m):
                ring = np.vstack([xy, xy[:1]])
                ax.plot(ring[:, 0], ring[:, 1], np.full(5, z), color="0.4", lw=0.8)
            for x, y in xy:
                ax.plot([x, x], [y, y], [0, o.height_m], color="0.4", lw=0.8)
        for p in field.pads:
            ax.scatter([p.x_m], [p.y_m], [0.0], marker="s", s=40, color="0.2")
    for k, (a, r) in enumerate(zip(aligned, results)):
        color = COLORS[k % len(COLORS)]
        xyz = a.xyz_m
        ax.plot(xyz[:, 0], xyz[:, 1], xyz[:, 2], color=color, lw=1.0, alpha=0.5)
        w = _window_slice(a, r)
        ax.plot(xyz[w, 0], xyz[w, 1], xyz[w, 2], color=color, lw=2.0, label=_name(a, r))
        ax.scatter(*xyz[0], color=color, marker="o", s=20)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(f"{TASK_TITLES[results[0].task]}: 3D trajectory (window bold)")
    ax.legend(loc="upper left")
    return _png(fig)


def birds_eye(aligned: Sequence[AlignedTrack], results: Sequence[TaskResult]) -> bytes:
    from matplotlib.patches import Polygon, Rectangle

    fig = _new_figure()
    ax = fig.add_subplot()
    field = _field(aligned)
    if field is not None:
        for o in field.obstacles:
            ax.add_patch(Polygon(_obstacle_corners(o), closed=True, color="0.55", zorder=1))
            ax.annotate(
                o.name,
                (o.x_m, o.y_m),
                textcoords="offset points",
                xytext=(0, 8),
                ha="center",
                fontsize=8,
            )
        for p in field.pads:
            ax.add_patch(
                Rectangle(
                    (p.x_m - p.size_m / 2, p.y_m - p.size_m / 2),
                    p.size_m,
                    p.size_m,
                    fill=False,
                    lw=1.5,
                    ec="0.1",
                    zorder=1,
                )
            )
            ax.annotate(
                f"{p.name} pad",
                (p.x_m, p.y_m),
                textcoords="offset points",
                xytext=(0, -14),
                ha="center",
                fontsize=8,
            )
    for k, (a, r) in enumerate(zip(aligned, results)):
        color = COLORS[k % len(COLORS)]
        xyz = a.xyz_m
        ax.plot(xyz[:, 0], xyz[:, 1], color=color, lw=1.0, alpha=0.5, zorder=2)
        w = _window_slice(a, r)
        ax.plot(xyz[w, 0], xyz[w, 1], color=color, lw=2.0, label=_name(a, r), zorder=3)
        ax.plot(xyz[0, 0], xyz[0, 1], "o", color=color, zorder=4)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3)
    ax.set_xlabel("x, longitudinal (m)")
    ax.set_ylabel("y, lateral (m)")
    ax.set_title(f"{TASK_TITLES[results[0].task]}: bird's-eye view (window bold)")
    ax.legend(loc="best")
    return _png(fig)


def position_history(aligned: Sequence[AlignedTrack], results: Sequence[TaskResult]) -> bytes:
    """Rows x, y, z; one column per flight; time from take-off; window shaded."""
    fig = _new_figure()
    n = len(aligned)
    axes = fig.subplots(3, n, sharey="row", squeeze=False)
    for k, (a, r) in enumerate(zip(aligned, results)):
        color = COLORS[k % len(COLORS)]
        t = a.t_s - r.takeoff_s
        for row, (axis, name) in enumerate(zip(a.xyz_m.T, ("x (m)", "y (m)", "z (m)"))):
            ax = axes[row][k]
            ax.axvspan(
                r.window_start_s - r.takeoff_s,
                r.window_end_s - r.takeoff_s,
                color=color,
                alpha=0.15,
                lw=0,
            )
            ax.plot(t, axis, color=color, lw=1.0)
            ax.grid(True, lw=0.3)
            if k == 0:
                ax.set_ylabel(name)
        axes[0][k].set_title(_name(a, r), fontsize=9)
        axes[2][k].set_xlabel("time since take-off (s)")
    fig.suptitle(f"{TASK_TITLES[results[0].task]}: position history (window shaded)")
    return _png(fig)


RENDERERS = {"trajectory3d": trajectory_3d, "birdseye": birds_eye, "history": position_history}


def render(kind: str, aligned: Sequence[AlignedTrack], results: Sequence[TaskResult]) -> bytes:
    if kind not in RENDERERS:
        raise ValueError(f"Unknown plot '{kind}'; use one of: {', '.join(PLOTS)}.")
    return RENDERERS[kind](aligned, results)


def write_all(
    aligned: Sequence[AlignedTrack], results: Sequence[TaskResult], out_dir: Path, prefix: str
) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for kind in PLOTS:
        path = out_dir / f"{prefix}_{kind}.png"
        path.write_bytes(render(kind, aligned, results))
        paths.append(path)
    return paths


def _window_slice(a: AlignedTrack, r: TaskResult) -> slice:
    i0 = int(np.searchsorted(a.t_s, r.window_start_s, side="left"))
    i1 = int(np.searchsorted(a.t_s, r.window_end_s, side="right"))
    return slice(i0, i1)
