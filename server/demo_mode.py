"""Demonstration mode: a pilot flies the chosen task N times, each attempt one recorded
session tagged with the pilot's name and `human` (session.json `demonstration`).

A run starts with the task chosen on the pilot page (server.trials), the pilot's name
and N. While it runs, the recorder writes the next attempt's tag into each session that
starts (`Recorder.demonstration`); when a session of the run ends, the attempt is counted
and the tag moves to the next one, and after the N-th the run ends by itself. Every
session the recorder writes meanwhile is an attempt, started by arming or by REC alike.
The station scores each attempt at the disarm as any trial (server.trials); whether it
counts is that score's validity (analysis.selection.trial_failed).

The run is kept in the sessions folder (`DEMO_RUN_FILE`, written whole then renamed), so
a reloaded page or a restarted station goes on with it; a run whose task is no longer the
chosen one after a restart is ended. A session cut off by the station's death is not
counted (its end was never seen): that attempt is flown again. While a run is active the
task cannot change (routes.task refuses), so all its attempts are of one task.
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
from pathlib import Path

from pydantic import BaseModel, Field, ValidationError

from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import PILOT_HUMAN, Demonstration, SessionMeta
from fpv_station.companion.recording.recorder import Recorder, Spawn
from fpv_station.server.errors import Conflict
from fpv_station.server.trials import Trials, write_json

log = logging.getLogger(__name__)

DEMO_RUN_FILE = "demo_run.json"  # in the sessions folder: the current or last run
MAX_ATTEMPTS = 50


class DemoRun(BaseModel):
    """One pilot's run of attempts at one task."""

    pilot: str
    attempts: int = Field(ge=1, le=MAX_ATTEMPTS)
    run: str  # its start, UTC: the tag's `run`
    task_id: int
    task_name: str
    sessions: list[str] = Field(default_factory=list)  # the attempts flown, in order
    ended: str | None = None  # None: running; else why it ended, in words

    @property
    def active(self) -> bool:
        return self.ended is None

    def tag(self) -> Demonstration:
        """The tag of the next attempt."""
        return Demonstration(
            kind=PILOT_HUMAN,
            pilot=self.pilot,
            run=self.run,
            attempt=len(self.sessions) + 1,
            attempts=self.attempts,
        )


class DemoMode:
    def __init__(self, trials: Trials, recorder: Recorder, spawn: Spawn) -> None:
        self.trials = trials
        self.recorder = recorder
        self.run: DemoRun | None = None  # the current run, or the last one
        self._spawn = spawn
        self._file = recorder.store.root / DEMO_RUN_FILE
        self._save_lock = threading.Lock()
        recorder.session_end_hooks.append(self._on_session_end)
        self._load()

    @property
    def active(self) -> DemoRun | None:
        return self.run if self.run is not None and self.run.active else None

    def start(self, pilot: str, attempts: int) -> DemoRun:
        """Start a run of `attempts` at the chosen task (name and count already checked)."""
        if (run := self.active) is not None:
            raise Conflict(
                f"{run.pilot}'s run is on (attempt {len(run.sessions) + 1} of "
                f"{run.attempts}); end it first."
            )
        task = self.trials.selected
        if task is None:
            raise Conflict("Choose the flight task first: a demonstration is of one task.")
        self.run = DemoRun(
            pilot=pilot,
            attempts=attempts,
            run=layout.utc_label(),
            task_id=task.id,
            task_name=task.name,
        )
        self.recorder.demonstration = self.run.tag()
        log.info("demonstration run %s: %s, %d attempts", self.run.run, pilot, attempts)
        return self.run

    def end(self, why: str) -> DemoRun | None:
        """End the active run (a session being recorded keeps its tag)."""
        run = self.active
        if run is not None:
            run.ended = why
            self.recorder.demonstration = None
            log.info("demonstration run %s ended: %s", run.run, why)
        return run

    def recording_attempt(self) -> int | None:
        """The attempt being recorded now, if the session running is one of this run's."""
        session = self.recorder.session
        demo = None if session is None else session.demonstration
        run = self.active
        return demo.attempt if run is not None and demo and demo.run == run.run else None

    def attempts_flown(self) -> list[tuple[str, SessionMeta | None]]:
        """Blocking: the run's sessions with their metadata (None: unreadable, deleted)."""
        run = self.run
        return (
            [] if run is None else [(s, self.recorder.store.meta_or_none(s)) for s in run.sessions]
        )

    def _on_session_end(self, meta: SessionMeta, folder: Path) -> None:
        run = self.active
        demo = meta.demonstration
        if run is None or demo is None or demo.run != run.run:
            return
        run.sessions.append(meta.id)
        if len(run.sessions) >= run.attempts:
            self.end(f"all {run.attempts} attempts flown")
        else:
            self.recorder.demonstration = run.tag()
        self.save_soon()

    # -- kept over a restart ---------------------------------------------------------------

    def save_soon(self) -> None:
        """Keep the run, off the event loop."""
        self._spawn("demo-run-save", asyncio.to_thread(self.save))

    def save(self) -> None:
        """Blocking: the run as it is now, written whole then renamed."""
        with self._save_lock:
            run = self.run
            try:
                write_json(self._file, None if run is None else run.model_dump(mode="json"))
            except OSError as exc:  # the run goes on until the station stops
                log.error("cannot keep the demonstration run in %s: %s", self._file, exc)

    def _load(self) -> None:
        if not self._file.is_file():
            return
        try:
            data = json.loads(self._file.read_text())
            self.run = None if data is None else DemoRun.model_validate(data)
        except (OSError, ValueError, ValidationError) as exc:
            log.warning("demonstration run in %s not used: %s", self._file, exc)
            return
        run = self.active
        if run is None:
            return
        selected = self.trials.selected
        if selected is None or selected.id != run.task_id:
            run.ended = "the chosen task changed while the station was stopped"
            self.save()
            return
        self.recorder.demonstration = run.tag()
