"""Figures of the autopilot's own log on the session clock (`analysis.onboard_log`): the
IMU (gyro and accelerometer) and rate tracking (each axis' rate setpoint against the
measured rate), the view a tuner reads first. Built as `analysis.plots` builds its
figures (Agg, no pyplot, a fixed size).
"""

from __future__ import annotations

import numpy as np

from fpv_station.analysis.onboard_log import SessionOnboard
from fpv_station.analysis.plots import COLORS, _new_figure, _png

_AXES = ("roll", "pitch", "yaw")


def onboard_figure(onboard: SessionOnboard, title: str) -> bytes:
    """A PNG: gyro, accelerometer, then roll/pitch/yaw rate against its setpoint (deg/s),
    against the session clock; a stream the log lacks leaves its panel out."""
    streams = onboard.log.streams
    panels: list[str] = []
    if "imu" in streams:
        panels += ["gyro", "accel"]
    if "rates" in streams:
        panels += list(_AXES)
    if not panels:
        raise ValueError(f"{onboard.log.path.name} has no IMU or rates to plot.")
    fig = _new_figure()
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for ax, panel in zip(axes, panels):
        if panel in ("gyro", "accel"):
            imu = streams["imu"]
            t = onboard.t_s("imu")
            unit = "rad_s" if panel == "gyro" else "m_s2"
            for k, a in enumerate("xyz"):
                col = imu.columns[f"{panel}_{a}_{unit}"]
                ax.plot(t, col, lw=0.6, color=COLORS[k], label=a)
            ax.set_ylabel("gyro (rad/s)" if panel == "gyro" else "accel (m/s²)")
            ax.legend(loc="upper right", fontsize="small", ncol=3)
            continue
        t = onboard.t_s("rates")
        ax.plot(
            t,
            np.degrees(streams["rates"].columns[f"{panel}_rad_s"]),
            lw=0.6,
            color=COLORS[0],
            label="measured",
        )
        if "rates_setpoint" in streams:
            sp = streams["rates_setpoint"].columns[f"{panel}_rad_s"]
            ax.plot(
                onboard.t_s("rates_setpoint"),
                np.degrees(sp),
                lw=0.6,
                color=COLORS[1],
                label="setpoint",
            )
        ax.set_ylabel(f"{panel} (°/s)")
        ax.legend(loc="upper right", fontsize="small", ncol=2)
    axes[-1].set_xlabel(
        f"session time (s; log placed by {onboard.clock.method if onboard.clock else '?'})"
    )
    axes[0].set_title(f"{title}: onboard log ({onboard.log.path.name})")
    return _png(fig)
