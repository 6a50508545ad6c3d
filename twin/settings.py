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

    # scene TOML; None = the built-in field of the paper
    scene: Annotated[Path | None, checked_by(_scene_loads)] = None
    seed: int = 0
    physics_hz: float = Field(250.0, ge=250.0, le=2000.0)
    realtime_factor: float = Field(1.0, gt=0, le=100.0)
    wind_east_mps: float = 0.0
    wind_north_mps: float = 0.0
    gust_std_mps: float = Field(0.0, ge=0)
    turbulence_std_mps: float = Field(0.0, ge=0)  # Dryden-like (twin.dynamics.Wind)
    sensor_noise: bool = True
    gps_rate_hz: float = Field(5.0, ge=1.0, le=20.0)
    max_vel_xy_mps: float = Field(5.0, gt=0, le=20.0)
    rates_hz: dict[str, float] = Field(default_factory=dict)  # MAVLink stream rates by name
    fpv_noise: bool = False  # analog-FPV look on the rendered cameras (rate: cameras.*.fps)
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
