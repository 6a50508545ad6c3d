"""The session format in one place: folder naming, file layout and CSV column names.

Everything that writes or reads a session (the recorder, the REST routes, analysis, the
3D trajectory) takes names from here; `docs/SESSION_FORMAT.md` describes the same
layout for people. Bump `FORMAT_VERSION` when a reader would misread the old layout.

    <sessions_dir>/<session id>/          id = "20261122T035500Z_sim" (UTC start + source tag)
        session.json                      metadata and quality report (SESSION_JSON)
        telemetry.csv                     fixed-rate rows (TELEMETRY_CSV, telemetry_columns())
        mavlink.tlog                      every MAVLink packet received (MAVLINK_TLOG)
        front/frames.mjpeg                every frame's JPEG bytes as streamed, back to back
                                          (frames_pack_relpath; companion.recording.frame_pack)
        front/frames.csv                  one row per frame written (FRAME_COLUMNS): its name
                                          front/00000042.jpg (frame_relpath), offset and bytes
        bottom/...                        the same for the bottom camera

Format 1 (sessions recorded before the frame pack) kept each frame in a file of its own,
front/00000042.jpg, and frames.csv had no `offset` column; every reader still reads it.
"""

from __future__ import annotations

import dataclasses
import re
import time
import typing
from datetime import UTC, datetime
from typing import Any

from fpv_station.companion.vehicle_state import LOG_GROUPS, VehicleState

FORMAT_VERSION = 2  # 2: frames in one frames.mjpeg per camera; 1: a file per frame
FORMAT_FILE_PER_FRAME = 1  # the last version with a file per frame

SESSION_JSON = "session.json"
TELEMETRY_CSV = "telemetry.csv"
MAVLINK_TLOG = "mavlink.tlog"  # records as core.mavlink.tlog_records writes them
FRAMES_CSV = "frames.csv"  # inside each camera folder
FRAMES_PACK = "frames.mjpeg"  # inside each camera folder: the frames' JPEGs back to back
MESSAGES_CSV = "messages.csv"  # what the vehicle said: STATUSTEXT and COMMAND_ACK
MESSAGE_COLUMNS: tuple[str, ...] = (
    "t_s",
    "t_wall",
    "severity",
    "kind",
    "text",
    "command",
    "result",
)
CAMERAS: tuple[str, ...] = ("front", "bottom")

# Session ids: UTC start time in ISO 8601 basic format, "_", a short source tag; a "-N"
# suffix on the tag when two sessions start in the same second.
SESSION_TIME_FORMAT = "%Y%m%dT%H%M%SZ"
SESSION_ID_RE = re.compile(r"^[0-9]{8}T[0-9]{6}Z_[a-z0-9]+(-[a-z0-9]+)*$")
SESSION_ID_MAX_LEN = 64
SOURCE_TAG_MAX_LEN = 16

# Frame names: zero-padded sequence number so that a plain sort is capture order. A
# frame's name is what the CSVs and the file route call it; in format 1 it was a file.
FRAME_PATH_TEMPLATE = "{camera}/{seq:08d}.jpg"  # relative to the session folder
FRAME_NAME_RE = re.compile(r"^([0-9]{8,})\.jpg$")  # the file name part, group 1 = seq

# Session states recorded in session.json "status".
STATUS_RECORDING = "recording"  # being written now (or cut off, until the next start)
STATUS_COMPLETE = "complete"  # stopped cleanly
STATUS_INTERRUPTED = "interrupted"  # the process died while recording (power cut, kill -9)
STATUS_CUT_SHORT = "cut_short"  # stopped by a failed write (disk full, EMFILE, EIO)

# The session clock and wall clock columns, first in telemetry.csv.
TIME_COLUMNS: tuple[str, ...] = ("t_s", "wall_time")
# Per camera, after the state columns: newest frame at the row's instant.
CAMERA_COLUMN_FIELDS: tuple[str, ...] = ("seq", "file", "t_wall", "skew_s")
# front/frames.csv and bottom/frames.csv: `offset` is the frame's first byte in the
# camera's FRAMES_PACK, `bytes` its length. Format 1 had no `offset` (FRAME_COLUMNS_V1).
FRAME_COLUMNS_V1: tuple[str, ...] = ("seq", "file", "t_s", "t_wall", "width", "height", "bytes")
FRAME_COLUMNS: tuple[str, ...] = (*FRAME_COLUMNS_V1, "offset")


def frame_relpath(camera: str, seq: int) -> str:
    """Path of frame `seq` of `camera` relative to the session folder (as in the CSVs)."""
    return FRAME_PATH_TEMPLATE.format(camera=camera, seq=seq)


def frames_csv_relpath(camera: str) -> str:
    return f"{camera}/{FRAMES_CSV}"


def frames_pack_relpath(camera: str) -> str:
    return f"{camera}/{FRAMES_PACK}"


def source_tag(source: str) -> str:
    """A short folder-safe tag for a link source string ("sim", "serial", "udp", ...)."""
    s = source.strip().lower()
    if s.startswith(("udpin:", "udpout:", "udp:", "udpbcast:")):
        return "udp"
    if s.startswith(("tcp:", "tcpin:")):
        return "tcp"
    if s.startswith("replay:"):
        return "replay"
    if s.startswith(("/dev/", "com")):
        return "serial"
    tag = re.sub(r"[^a-z0-9]+", "-", s).strip("-")[:SOURCE_TAG_MAX_LEN].strip("-")
    return tag or "unknown"


def session_id_for(start_wall: float, source: str, suffix: int = 0) -> str:
    """The id (folder name) of a session that started at `start_wall` (Unix s)."""
    stamp = datetime.fromtimestamp(start_wall, tz=UTC).strftime(SESSION_TIME_FORMAT)
    tag = source_tag(source)
    return f"{stamp}_{tag}" + (f"-{suffix}" if suffix else "")


def session_start_from_id(session_id: str) -> float | None:
    """The UTC start time (Unix s, whole seconds) encoded in a session id, or None."""
    try:
        stamp = datetime.strptime(session_id.split("_", 1)[0], SESSION_TIME_FORMAT)
    except ValueError:
        return None
    return stamp.replace(tzinfo=UTC).timestamp()


def is_valid_session_id(session_id: str) -> bool:
    return (
        isinstance(session_id, str)
        and len(session_id) <= SESSION_ID_MAX_LEN
        and SESSION_ID_RE.fullmatch(session_id) is not None
    )


def _tuple_length(group_type: type, f: dataclasses.Field[Any]) -> int | None:
    """Length of a tuple field from its default (the state fixes it), None if not a tuple."""
    if f.default_factory is not dataclasses.MISSING:
        default = f.default_factory()
    else:
        default = f.default
    return len(default) if isinstance(default, tuple) else None


def state_fields() -> list[tuple[str, str, int | None]]:
    """(group, field, tuple index or None) for every flattened VehicleState column."""
    out: list[tuple[str, str, int | None]] = []
    hints = typing.get_type_hints(VehicleState)
    for group in dataclasses.fields(VehicleState):
        if group.name in LOG_GROUPS:  # logs have their own file (MESSAGES_CSV)
            continue
        group_type = hints[group.name]
        for f in dataclasses.fields(group_type):
            n = _tuple_length(group_type, f)
            if n is None:
                out.append((group.name, f.name, None))
            else:
                out.extend((group.name, f.name, i) for i in range(n))
    return out


def state_columns() -> tuple[str, ...]:
    """VehicleState flattened generically: `group.field`, tuples as `group.field.N`."""
    return tuple(f"{g}.{f}" if i is None else f"{g}.{f}.{i}" for g, f, i in state_fields())


def camera_columns(cameras: tuple[str, ...] = CAMERAS) -> tuple[str, ...]:
    return tuple(f"{cam}.{field}" for cam in cameras for field in CAMERA_COLUMN_FIELDS)


def telemetry_columns(cameras: tuple[str, ...] = CAMERAS) -> tuple[str, ...]:
    """Every column of telemetry.csv, in order."""
    return TIME_COLUMNS + state_columns() + camera_columns(cameras)


def utc_label(t_wall: float | None = None) -> str:
    """ISO 8601 UTC label for session.json (people read it; t_wall is kept alongside)."""
    t = time.time() if t_wall is None else t_wall
    return datetime.fromtimestamp(t, tz=UTC).isoformat(timespec="milliseconds")
