"""Selected sessions exported to a learning format from the sessions page, off the
station's process.

An export is `fpv-station export --select ...` run by the station: the sessions chosen by
`analysis.selection` (the same rule, the same text), handed to `learn.export
.export_recordings` (the same export) in a process of its own. Encoding videos takes
minutes of a core; in the station's process it would hold the interpreter's lock and
delay the flight state sent to the pilot. The process is spawned (a fork of a threaded
server is unsafe) at the analysis worker's lower priority, and ends with the station
(`analysis_worker.worker_init`). One export runs at a time; another is refused (409).

Each export is a folder `<sessions_dir>/exports/<id>/`: the dataset in `<format>/` and
`export.json` saying what made it (selection, sessions, format) and how it went (`state`:
running, done, failed; the summary, or why it failed). The station lists the folders
(so exports outlive a restart; one left `running` by a station that stopped is
`interrupted`) and serves each finished one as a zip.
"""

from __future__ import annotations

import asyncio
import builtins
import contextlib
import logging
import multiprocessing
import os
import re
from pathlib import Path
from typing import Any

from pydantic import BaseModel, Field, ValidationError

from fpv_station.analysis.errors import without_dirs
from fpv_station.analysis.selection import Selection, select_sessions
from fpv_station.companion.recording import layout
from fpv_station.companion.recording.store import SessionStore
from fpv_station.core.spawn import Spawn
from fpv_station.server.errors import BadRequest, Conflict, NotFound
from fpv_station.server.trials import write_json

log = logging.getLogger(__name__)

EXPORTS_DIR = "exports"  # in the sessions folder
EXPORT_JSON = "export.json"
_ID = re.compile(r"\d{8}T\d{6}Z(?:-\d{1,3})?")

RUNNING, DONE, FAILED, INTERRUPTED = "running", "done", "failed", "interrupted"


class ExportRecord(BaseModel):
    """export.json: what an export was made of and how it went."""

    id: str
    select: str
    include_failed: bool
    format: str
    sessions: list[str]
    left_out_failed: int = 0  # sessions of the selection kept out by a failed trial
    state: str = RUNNING
    message: str = ""
    started_utc: str
    ended_utc: str | None = None
    episodes: int | None = None
    frames: int | None = None
    skipped: list[str] = Field(default_factory=list)  # recordings without a flight, why


class Exports:
    def __init__(self, store: SessionStore, spawn: Spawn) -> None:
        self.store = store
        self.root = store.root / EXPORTS_DIR
        self._spawn = spawn
        self._running: ExportRecord | None = None
        self._lock = asyncio.Lock()  # one start at a time: the check and the claim together

    async def start(self, selection: Selection, fmt: str) -> ExportRecord:
        async with self._lock:
            return await self._start(selection, fmt)

    async def _start(self, selection: Selection, fmt: str) -> ExportRecord:
        if self._running is not None:
            raise Conflict(f"Export {self._running.id} is running; wait for it to end.")
        chosen = await asyncio.to_thread(select_sessions, self.store, selection)
        if not chosen.sessions:
            raise BadRequest(f"No session is selected by '{selection.text()}'.")
        record = ExportRecord(
            id=await asyncio.to_thread(self._new_id),
            select=selection.text(),
            include_failed=selection.include_failed,
            format=fmt,
            sessions=chosen.sessions,
            left_out_failed=len(chosen.failed),
            started_utc=layout.utc_label(),
        )
        folder = self.root / record.id
        await asyncio.to_thread(_write, folder, record)
        self._running = record
        paths = [str(self.store.resolve(s)) for s in record.sessions]
        self._spawn(f"export-{record.id}", self._run(record, folder, paths))
        return record

    async def _run(self, record: ExportRecord, folder: Path, paths: list[str]) -> None:
        ctx = multiprocessing.get_context("spawn")
        proc = ctx.Process(
            target=run_export, args=(record, str(folder), paths), name=f"export {record.id}"
        )
        try:
            proc.start()
            await asyncio.to_thread(proc.join)
            if proc.exitcode != 0:  # killed (out of memory), or the station stopping
                done = await asyncio.to_thread(read_record, folder)
                if done is None or done.state == RUNNING:
                    failed = record.model_copy(
                        update={
                            "state": FAILED,
                            "message": f"the export process stopped (exit code {proc.exitcode})",
                            "ended_utc": layout.utc_label(),
                        }
                    )
                    await asyncio.to_thread(_write, folder, failed)
        finally:
            if proc.is_alive():  # cancelled: the station stops
                proc.terminate()
                await asyncio.to_thread(proc.join, 5.0)
            self._running = None

    def _new_id(self) -> str:
        base = layout.utc_label().replace("-", "").replace(":", "")[:15] + "Z"
        for k in range(1000):
            name = base if k == 0 else f"{base}-{k}"
            if not (self.root / name).exists():
                return name
        raise Conflict("Too many exports this second; try again.")

    def list(self) -> list[ExportRecord]:
        """Blocking: every export on disk, newest first."""
        out = []
        with contextlib.suppress(OSError):
            for entry in sorted(os.scandir(self.root), key=lambda e: e.name, reverse=True):
                if _ID.fullmatch(entry.name) and entry.is_dir(follow_symlinks=False):
                    record = self.get(entry.name)
                    if record is not None:
                        out.append(record)
        return out

    def get(self, export_id: str) -> ExportRecord | None:
        """Blocking: an export's record, `interrupted` if no process is making it now."""
        if not _ID.fullmatch(export_id):
            return None
        record = read_record(self.root / export_id)
        if record is None:
            return None
        running = self._running is not None and self._running.id == export_id
        if record.state == RUNNING and not running:
            return record.model_copy(update={"state": INTERRUPTED})
        return record

    def files(self, export_id: str) -> builtins.list[tuple[str, Path]]:
        """Blocking: (name in the zip, path) of a finished export's files."""
        record = self.get(export_id)
        if record is None:
            raise NotFound(f"No export '{export_id[:40]}'.")
        if record.state != DONE:
            raise Conflict(f"Export {export_id} is {record.state}, not done.")
        folder = self.root / export_id
        out = []
        for dirpath, dirnames, names in os.walk(folder, followlinks=False):
            dirnames.sort()
            for name in sorted(names):
                p = Path(dirpath) / name
                if p.is_file() and not p.is_symlink():
                    out.append((f"{export_id}/{p.relative_to(folder).as_posix()}", p))
        return out


def read_record(folder: Path) -> ExportRecord | None:
    try:
        return ExportRecord.model_validate_json((folder / EXPORT_JSON).read_bytes())
    except (OSError, ValueError, ValidationError):
        return None


def _write(folder: Path, record: ExportRecord) -> None:
    write_json(folder / EXPORT_JSON, record.model_dump(mode="json"))


def run_export(record: ExportRecord, folder: str, paths: list[str]) -> None:
    """In the export's process: the export, then its record (done or failed)."""
    from fpv_station.server.analysis_worker import worker_init

    worker_init()
    update: dict[str, Any]
    try:
        from fpv_station.learn.export import ExportOptions, export_recordings

        s = export_recordings(
            [Path(p) for p in paths],
            record.format,
            Path(folder) / record.format,
            ExportOptions(workers=1),
        )
        update = {"state": DONE, "episodes": s.episodes, "frames": s.frames}
        update["skipped"] = [without_dirs(w) for w in s.skipped]
        update["message"] = f"{s.episodes} episodes from {s.recordings} sessions"
    except ImportError as exc:
        update = {
            "state": FAILED,
            "message": f"the `learn` extra is not installed here ({exc.name}): "
            "pip install 'fpv-station[learn]'",
        }
    except Exception as exc:  # a recording it cannot read, a full disk: in the record
        log.exception("export %s failed", record.id)
        update = {"state": FAILED, "message": without_dirs(str(exc))}
    update["ended_utc"] = layout.utc_label()
    _write(Path(folder), record.model_copy(update=update))
