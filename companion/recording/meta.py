"""session.json: the typed metadata and quality report of one session.

Written by the recorder at start (status "recording"), rewritten atomically every few
seconds while recording and at stop; read by the session store, the REST routes and
analysis. Unknown keys are kept on read so that newer writers do not break older readers.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, Field

from fpv_station.companion.recording.layout import FORMAT_VERSION, STATUS_RECORDING
from fpv_station.companion.timesync import VehicleClock
from fpv_station.core.geodesy import enu_to_geodetic

if TYPE_CHECKING:
    from fpv_station.core.scene import Scene, Task


class _Model(BaseModel):
    model_config = ConfigDict(extra="allow")


class CameraQuality(_Model):
    configured_fps: float | None = None
    achieved_fps: float | None = None  # frames written / time between first and last
    # Frames the camera produced while recording (by sequence numbers, from the first one
    # the recorder saw): always frames_written + frames_dropped.
    frames_captured: int = 0
    frames_written: int = 0
    # Frames the camera captured that never reached the disk: skipped by the Latest slot
    # before the consumer saw them, or refused because the writer queue was full.
    frames_missed: int = 0
    frames_dropped_queue: int = 0
    frames_dropped: int = 0  # the sum of both
    first_seq: int | None = None
    last_seq: int | None = None
    skew_max_s: float | None = None  # |row time - frame capture time| over the rows
    skew_p99_s: float | None = None


class LinkLoss(_Model):
    start_s: float  # session clock
    end_s: float | None = None  # None: the link was still lost when the session ended


class Quality(_Model):
    telemetry_rate_hz: float = 0.0  # configured
    telemetry_rows: int = 0
    telemetry_achieved_hz: float | None = None
    telemetry_rows_dropped: int = 0
    # Row instants skipped because what held then is not known: the writer thread (which
    # takes a live session's rows) was held up longer than the state history spans (a
    # stalled disk). The grid stays fixed: gaps, never rows bunched or with later states.
    telemetry_ticks_late: int = 0
    tlog_packets: int = 0
    tlog_packets_dropped: int = 0
    cameras: dict[str, CameraQuality] = Field(default_factory=dict)
    link_loss: list[LinkLoss] = Field(default_factory=list)
    # Silences of the autopilot longer than telemetry_gap_s (flags.QUALITY_THRESHOLDS),
    # shorter than a link loss but already a hole in the flight's record.
    telemetry_gap_s: float | None = None
    telemetry_gaps: list[LinkLoss] = Field(default_factory=list)


class Arming(_Model):
    """Where and at which altitude the vehicle was armed (the pilot's altitude reference)."""

    t_s: float | None = None
    reference_alt_m: float | None = None
    home_lat_deg: float | None = None
    home_lon_deg: float | None = None
    # What measured the pilot's altitude (the state's `altitude.source`): "alt", or
    # "relative_alt" where the two disagreed on the ground (old firmware's GPS altitude
    # in `alt`). None: a session written before it was recorded.
    altitude_source: str | None = None


class Missed(_Model):
    """The part of the flight before the session: it started with the vehicle already
    armed (its start refused and retried, the flight's earlier session cut short, a
    station started mid-flight, or started by hand)."""

    # Seconds the vehicle had been armed when the session started (from its first
    # HEARTBEAT saying armed; a session started on arming: that start's own latency).
    armed_before_start_s: float
    # Of those, the seconds no session recorded: since arming, or since the end of the
    # station's previous session when that was later (the flight's earlier session).
    unrecorded_s: float
    reason: str | None = None  # why: the refused start's error, or the failed write's


class Recovery(_Model):
    """What the station found in the files of a session whose writer was cut off (kill -9,
    power loss, a failed write) and what it repaired (companion.recording.ondisk); the
    quality counts of such a session are those on disk."""

    utc: str  # when the files were counted
    telemetry_cut_line: bool = False  # telemetry.csv ends in a partial line (readers skip it)
    tlog_cut_record: bool = False  # mavlink.tlog ends in a partial record (readers skip it)
    frames_added: dict[str, int] = Field(default_factory=dict)  # complete JPEGs listed again
    frame_rows_removed: dict[str, int] = Field(default_factory=dict)  # rows of missing files
    partial_frames_removed: list[str] = Field(default_factory=list)  # cut JPEGs deleted
    # Complete JPEGs that frames.csv still does not list (it could not be rewritten).
    frames_unlisted: dict[str, int] = Field(default_factory=dict)
    # Format 2: bytes cut off the end of <camera>/frames.mjpeg, after its last listed
    # frame (the batch being written when the writer was cut off: no row names them).
    pack_tail_removed: dict[str, int] = Field(default_factory=dict)


class SessionTask(_Model):
    """The flight task the pilot chose before the session (from the scene file), so that
    the session, its analysis and an exported episode know what the flight was for."""

    id: int
    name: str
    analysis: str | None = None  # how it is scored: hover, a-to-b, obstacle, figure8
    scene: str  # the scene's name
    scene_file: str | None = None  # None: the default field
    start_pad: str
    end_pad: str
    altitude_m: float
    hold_s: float = 0.0
    reference_lat_deg: float | None = None  # the end pad: the analysis' +x reference
    reference_lon_deg: float | None = None
    procedure: list[str] = Field(default_factory=list)


def session_task(scene: Scene, scene_file: Path | None, task: Task) -> SessionTask:
    """What a session records of its task: the task, its scene and its +x reference (the
    pilot's choice in a recorded session, the flown task in a twin demonstration)."""
    end = scene.pad(task.end_pad)
    lat, lon, _ = enu_to_geodetic([end.x_m, end.y_m, 0.0], *scene.home_llh)
    return SessionTask(
        id=task.id,
        name=task.name,
        analysis=task.analysis_task,
        scene=scene.name,
        scene_file=str(scene_file) if scene_file is not None else None,
        start_pad=task.start_pad,
        end_pad=task.end_pad,
        altitude_m=task.altitude_m,
        hold_s=task.hold_s,
        reference_lat_deg=round(float(lat), 8),
        reference_lon_deg=round(float(lon), 8),
        procedure=list(task.procedure),
    )


PILOT_HUMAN = "human"
PILOT_SCRIPTED = "scripted"
PILOT_KINDS = (PILOT_HUMAN, PILOT_SCRIPTED)
PILOT_NAME_MAX = 40
# Letters (any script), digits, and inner spaces, dots, apostrophes and hyphens: no comma
# or '=' (a selection's separators), no path or markup characters.
_PILOT_NAME = re.compile(r"\w(?:[\w .'-]*\w)?")


def check_pilot_name(text: str) -> str:
    """A pilot's name as kept in session.json (stripped), or ValueError saying why not."""
    name = " ".join(str(text).split())
    if not name or len(name) > PILOT_NAME_MAX or not _PILOT_NAME.fullmatch(name):
        raise ValueError(
            f"a pilot's name is 1 to {PILOT_NAME_MAX} letters or digits, with inner spaces, "
            f"dots, apostrophes or hyphens (not {str(text)[:60]!r})"
        )
    return name


class Demonstration(_Model):
    """Who flew the session as a demonstration, so that every session used for learning
    says where it came from: a person in the pilot page's demonstration mode
    (server.demo_mode), or the twin's scripted pilot (learn.demos)."""

    kind: str  # PILOT_HUMAN or PILOT_SCRIPTED
    pilot: str  # the person's name as entered; "scripted" for the scripted pilot
    run: str  # the run of attempts this session belongs to (its start, UTC)
    attempt: int  # 1-based, within the run
    attempts: int  # the run's planned number of attempts


class TrialScore(_Model):
    """The task's analysis of this session, done when the vehicle disarmed."""

    task: str  # the analysis: hover, a-to-b, ...
    ok: bool
    reason: str | None = None  # in plain words, when there is no score
    scored_utc: str
    result: dict[str, Any] | None = None  # analysis.tasks.TaskResult as a dict


class SessionClock(_Model):
    """Which clock named and stamped the session (companion.recording.session_clock):
    a Pi has no real-time clock, the vehicle's GPS knows UTC."""

    used: str  # "station", "vehicle" (its GPS time) or "source" (a replayed log's own)
    reason: str
    # UTC used = any wall time of this session (start_wall, wall_time, t_wall) + offset_s.
    offset_s: float = 0.0
    station_synced: bool | None = None  # the kernel's answer at the start; None: unknown
    station_start_wall: float  # the station's clock at the start
    vehicle_start_utc: float | None = None  # the vehicle's GPS time then, None: it had none
    vehicle_source: str | None = None  # "SYSTEM_TIME" or "GPS_RAW_INT"
    max_disagree_s: float
    # The folder name is chosen once, at the start; stamps follow a GPS time first heard
    # later in the session. This says which clock the name used.
    named_by: str | None = None
    # The vehicle's boot clock on the session clock (TIMESYNC, companion.timesync):
    # t_s = offset_s + boot_s * (1 + drift_ppm * 1e-6); None: no vehicle link.
    vehicle_boot: VehicleClock | None = None


class OnboardLog(_Model):
    """The autopilot's own flight log, downloaded into the session (companion.onboard_log)."""

    state: str  # complete, incomplete, no_log, failed, cancelled
    file: str | None = None  # onboard.ulg (PX4 ULog), onboard.bin (DataFlash); None: none
    bytes: int = 0  # in the file (the listed size when complete)
    complete: bool = False  # every byte of the vehicle's listed size came
    download_s: float | None = None
    log_id: int | None = None  # the vehicle's id of the log
    message: str = ""  # in plain words: what came, or why nothing did
    # Its first and last sample on the session clock and the vehicle clock's mapping
    # used, "timesync" or "delay" (analysis.onboard_log, session.json onboard_alignment).
    t_s: list[float] | None = None
    clock: str | None = None
    fetched_utc: str | None = None


class SessionMeta(_Model):
    format_version: int = FORMAT_VERSION
    id: str
    status: str = STATUS_RECORDING
    stop_reason: str | None = None
    start_wall: float  # the station's clock; see clock.offset_s for UTC
    start_utc: str  # in the clock chosen (clock.used)
    end_wall: float | None = None
    end_utc: str | None = None
    duration_s: float | None = None
    source: str = "unknown"
    cameras: list[str] = Field(default_factory=list)
    software_version: str = "unknown"
    settings: dict[str, Any] = Field(default_factory=dict)
    trigger: str | None = None  # "rest", "arm", "api", ...
    arming: Arming | None = None
    missed: Missed | None = None  # None: the vehicle was not armed when the session started
    quality: Quality = Field(default_factory=Quality)
    task: SessionTask | None = None
    score: TrialScore | None = None
    demonstration: Demonstration | None = None  # None: not flown as a demonstration
    recovery: Recovery | None = None  # set when the counts were taken from the files
    clock: SessionClock | None = None  # None: written before the station chose clocks
    onboard_log: OnboardLog | None = None  # the autopilot's own log, once fetched


def write_meta(path: Path, meta: SessionMeta) -> None:
    """Write session.json atomically (temp file, fsync, rename) so a crash never halves it.

    On a full disk the temp file cannot be written; then the file is overwritten in place,
    which needs no new blocks while it does not grow past the ones it holds (the reason
    "disk full" must still reach session.json).
    """
    tmp = path.with_name(path.name + ".tmp")
    data = json.dumps(meta.model_dump(mode="json"), indent=2).encode()
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT) or not path.exists():
            raise
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        with open(path, "r+b") as f:
            f.write(data)
            f.truncate()
            f.flush()
            os.fsync(f.fileno())


def read_meta(path: Path) -> SessionMeta:
    """Read session.json; raises ValueError (with the file name) if it is unreadable."""
    try:
        return SessionMeta.model_validate_json(path.read_bytes())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read session metadata: {exc}") from None
