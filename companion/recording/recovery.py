"""At start: sessions still marked "recording" were cut off (power loss, kill -9).

Their files are readable up to the last flush; this completes their session.json from
what is on disk (rows and frames actually written, the last row's wall time) and marks
them "interrupted" so that nobody mistakes them for a session in progress.
"""

from __future__ import annotations

import csv
import logging
import os
from pathlib import Path

from companion.recording import layout
from companion.recording.meta import write_meta
from companion.recording.store import SessionStore

log = logging.getLogger(__name__)


def mark_interrupted(store: SessionStore, skip: set[str] | None = None) -> list[str]:
    """Mark every session left in status "recording" as interrupted; returns their ids."""
    marked = []
    for sid in store.ids():
        if skip and sid in skip:
            continue
        meta = store.meta_or_none(sid)
        if meta is None or meta.status != layout.STATUS_RECORDING:
            continue
        folder = store.resolve(sid)
        rows, last_wall = _count_rows(folder / layout.TELEMETRY_CSV)
        meta.status = layout.STATUS_INTERRUPTED
        meta.stop_reason = "interrupted: the station stopped while recording (power loss or kill)"
        meta.quality.telemetry_rows = rows
        if last_wall is not None:
            meta.end_wall = last_wall
            offset = meta.clock.offset_s if meta.clock is not None else 0.0
            meta.end_utc = layout.utc_label(last_wall + offset)
            meta.duration_s = round(last_wall - meta.start_wall, 3)
        for cam, cq in meta.quality.cameras.items():
            frames = _count_frames(folder / layout.frames_csv_relpath(cam))
            if frames is not None:
                cq.frames_written = frames
        try:
            write_meta(folder / layout.SESSION_JSON, meta)
        except OSError as exc:
            log.warning("cannot mark session %s interrupted: %s", sid, exc)
            continue
        log.warning("session %s was interrupted; marked as such", sid)
        marked.append(sid)
    return marked


def _complete_lines(path: Path) -> list[str]:
    """Lines of a CSV that ends where the writer was cut; a trailing partial line is dropped."""
    try:
        data = path.read_bytes()
    except OSError:
        return []
    end = data.rfind(b"\n")
    if end < 0:
        return []
    return data[: end + 1].decode("utf-8", errors="replace").splitlines()


def _count_rows(path: Path) -> tuple[int, float | None]:
    lines = _complete_lines(path)
    if len(lines) < 2:
        return 0, None
    try:
        wall_col = next(csv.reader([lines[0]])).index("wall_time")
        last_wall = float(next(csv.reader([lines[-1]]))[wall_col])
    except (ValueError, IndexError, StopIteration):
        last_wall = None
    return len(lines) - 1, last_wall


def _count_frames(path: Path) -> int | None:
    if not os.path.exists(path):
        return None
    return max(len(_complete_lines(path)) - 1, 0)
