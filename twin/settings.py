"""The digital twin's settings section (`[twin]`), composed by `server.settings`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import Field

from fpv_station.core.settings_section import Section, checked_by


def _scene_loads(path: Path) -> None:
    from fpv_station.core.scene import load_scene  # here: settings load without the scene code

    load_scene(path)  # SceneError (a ValueError) says which file and key


class TwinSettings(Section):
    """The embedded digital twin (`--source sim` and `fpv-station sim`)."""

    scene: Annotated[Path | None, checked_by(_scene_loads)] = Field(
        None,
        description="The scene TOML the twin flies (core/scenes/field.toml's format); None: "
        "the built-in field of the paper.",
    )
    seed: int = Field(0, description="Seed of the twin's randomness (noise, gusts).")
    physics_hz: float = Field(
        250.0, ge=250.0, le=2000.0, description="Fixed physics steps a second."
    )
    realtime_factor: float = Field(
        1.0, gt=0, le=100.0, description="Simulated seconds per wall second."
    )
    wind_east_mps: float = Field(
        0.0, description="Mean wind towards east (m/s); calm settings: the scene's [wind]."
    )
    wind_north_mps: float = Field(0.0, description="Mean wind towards north (m/s).")
    gust_std_mps: float = Field(0.0, ge=0, description="Gusts' standard deviation (m/s).")
    turbulence_std_mps: float = Field(
        0.0,
        ge=0,
        description="Dryden-like turbulence's standard deviation (m/s; twin.dynamics.Wind).",
    )
    sensor_noise: bool = Field(
        True, description="Noise on the twin's sensors (GPS, altitude, attitude)."
    )
    gps_rate_hz: float = Field(5.0, ge=1.0, le=20.0, description="GPS fixes a second.")
    max_vel_xy_mps: float = Field(
        5.0, gt=0, le=20.0, description="Horizontal speed limit (m/s): full stick in Position mode."
    )
    rates_hz: dict[str, float] = Field(
        default_factory=dict,
        description="MAVLink stream rates by message name, before any ground station asks.",
    )
    fpv_noise: bool = Field(
        False, description="An analog-FPV look on the rendered cameras (rate: cameras.*.fps)."
    )
    flight_log: bool = Field(
        True,
        description="Write the twin's own flight log (a PX4 ULog per armed period: IMU and "
        "rate setpoints at the physics rate) and serve it over the MAVLink log protocol.",
    )
    flight_log_dir: Path | None = Field(
        None,
        description="Where the twin keeps its flight logs (its SD card); None: a private "
        "folder removed when the twin stops.",
    )
