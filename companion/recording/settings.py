"""The recorder's settings section (`[recording]`), composed by `server.settings`."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field

from fpv_station.core.settings_section import Section


class RecordingSettings(Section):
    """Synchronized flight recording (companion.recording); format in docs/SESSION_FORMAT.md."""

    sessions_dir: Path = Path("./sessions")
    rate_hz: float = Field(30.0, ge=1, le=100)  # telemetry.csv rows per second
    auto_record_on_arm: bool = True
    post_disarm_tail_s: float = Field(5.0, ge=0, le=600)
    min_free_mb: float = Field(200.0, ge=0)  # stop cleanly under this much free disk
    row_queue: int = Field(2000, ge=10)  # bounded writer buffers (items)
    frame_queue: int = Field(90, ge=2)  # per camera
    packet_queue: int = Field(20000, ge=100)
    # Take UTC from the vehicle's GPS when the station's clock is this far off it (or not
    # synchronised at all): companion.recording.session_clock.
    clock_max_disagree_s: float = Field(5.0, gt=0)
    flush_interval_s: float = Field(0.5, gt=0, le=1.0)  # at most 1 s: kill -9 keeps all but it
