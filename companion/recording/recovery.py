"""At start: sessions still marked "recording" were cut off (power loss, kill -9).

Their files are readable up to the last flush; this counts what is on disk and makes the
frames.csv files list exactly the complete frames (`companion.recording.ondisk`), sets
their session.json counts and end to that, and marks them "interrupted" so that nobody
mistakes them for a session in progress.
"""

from __future__ import annotations

import logging

from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import write_meta
from fpv_station.companion.recording.ondisk import Census, apply_census, take_census
from fpv_station.companion.recording.store import SessionStore

log = logging.getLogger(__name__)


def mark_interrupted(store: SessionStore, skip: set[str] | None = None) -> list[str]:
    """Recover every session left in status "recording" and mark it interrupted; returns
    their ids."""
    marked = []
    for sid in store.ids():
        if skip and sid in skip:
            continue
        meta = store.meta_or_none(sid)
        if meta is None or meta.status != layout.STATUS_RECORDING:
            continue
        folder = store.resolve(sid)
        census: Census | None
        try:
            census = take_census(folder, meta.cameras, meta.start_wall)
        except OSError as exc:
            # This runs before the station serves: one unreadable session must not keep
            # it from starting. Its counts stay those it last wrote (no `recovery`).
            census = None
            log.warning("cannot count the files of interrupted session %s: %s", sid, exc)
        if census is not None:
            apply_census(meta, census, layout.utc_label())
        meta.status = layout.STATUS_INTERRUPTED
        meta.stop_reason = "interrupted: the station stopped while recording (power loss or kill)"
        try:
            write_meta(folder / layout.SESSION_JSON, meta)
        except OSError as exc:
            log.warning("cannot mark session %s interrupted: %s", sid, exc)
            continue
        if census is not None:
            log.warning(
                "session %s was interrupted; recovered %d rows, %s frames on disk",
                sid,
                census.telemetry_rows,
                {c: f.complete for c, f in census.frames.items()},
            )
        marked.append(sid)
    return marked
