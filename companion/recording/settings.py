"""The recorder's settings section (`[recording]`), composed by `server.settings`."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field

from fpv_station.core.settings_section import Section


class RecordingSettings(Section):
    """Synchronized flight recording (companion.recording); format in docs/SESSION_FORMAT.md."""

    sessions_dir: Path = Field(Path("./sessions"), description="Where session folders go.")
    rate_hz: float = Field(30.0, ge=1, le=100, description="telemetry.csv rows per second.")
    auto_record_on_arm: bool = Field(
        True, description="Start a session when the vehicle arms, stop it after the disarm."
    )
    post_disarm_tail_s: float = Field(
        5.0, ge=0, le=600, description="Seconds recorded after a disarm (the landing's end)."
    )
    min_free_mb: float = Field(
        200.0,
        ge=0,
        description="Stop cleanly, saying why in session.json, when free disk falls under "
        "this many MB.",
    )
    row_queue: int = Field(
        2000, ge=10, description="The writer's buffer of telemetry rows (items; bounded)."
    )
    frame_queue: int = Field(90, ge=2, description="The writer's buffer of frames, per camera.")
    packet_queue: int = Field(
        20000, ge=100, description="The writer's buffer of MAVLink packets for the tlog."
    )
    clock_max_disagree_s: float = Field(
        5.0,
        gt=0,
        description="Take UTC from the vehicle's GPS when the station's clock is this far "
        "off it (or not synchronised at all): companion.recording.session_clock.",
    )
    flush_interval_s: float = Field(
        0.5,
        gt=0,
        le=1.0,
        description="Seconds between flushes to disk; at most 1 s, so a kill -9 or a power "
        "loss keeps all but that.",
    )
