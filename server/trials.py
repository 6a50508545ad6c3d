"""Flight tasks in the pilot's hands: the task chosen for the next flights, written into
each session, and the trial scored the moment the vehicle disarms.

The scene is the station's one field (`core.scene`): `viser.field_file` when set, else the
twin's scene when flying the twin, else the default field (the paper's four tasks; its
pads only count for flights that start on them, as in `fpv-station analyze`). Scoring
runs `analysis.trial_score.score_and_store` on the finished session (the same call as
`fpv-station analyze --task T SESSION [--scene FILE]`) in a worker thread behind the
station's analysis limiter, and stores the result in the session's `session.json`.
The result says whether the trial is `valid` (no crash, no obstacle touched, landed on the
pad) and how far from the pad's centre it landed. The score is read by anonymous pages:
its texts name the session by its id, never by the server's folders.

The chosen task is kept in the sessions folder (`CHOSEN_TASK_FILE`, beside the sessions it
is written into), so that a restarted station flies on with it; a task its scene no
longer has is dropped with a log line.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import json
import logging
import os
from pathlib import Path
from typing import Any

import anyio

from fpv_station.analysis.errors import without_dirs
from fpv_station.analysis.tasks import PAPER_RESULTS
from fpv_station.analysis.trial_score import score_and_store
from fpv_station.companion.recording.meta import (
    SessionMeta,
    SessionTask,
    TrialScore,
    session_task,
)
from fpv_station.companion.recording.recorder import Recorder, Spawn
from fpv_station.core.scene import Scene, SceneError, load_scene
from fpv_station.server.settings import Settings

log = logging.getLogger(__name__)

MAX_ATTEMPTS_SHOWN = 20
CHOSEN_TASK_FILE = "chosen_task.json"  # in the sessions folder: {"scene": name, "task_id": n}


def public_score(score: TrialScore | None) -> TrialScore | None:
    """A stored score as a client may read it: a session scored by an older station may
    hold the server's folders in its reason or its result's source."""
    if score is None:
        return None
    update: dict[str, Any] = {}
    if score.reason is not None:
        update["reason"] = without_dirs(score.reason)
    if score.result is not None and isinstance(score.result.get("source"), str):
        update["result"] = {**score.result, "source": Path(score.result["source"]).name}
    return score.model_copy(update=update) if update else score


class Trials:
    """The chosen task, and the scores of the trials flown with it."""

    def __init__(
        self,
        scene: Scene,
        scene_file: Path | None,
        is_field: bool,
        recorder: Recorder | None,
        spawn: Spawn,
        limiter: anyio.CapacityLimiter,
    ) -> None:
        self.scene = scene
        self.scene_file = scene_file
        self.is_field = is_field  # the scene is the field being flown (not just its tasks)
        self.recorder = recorder
        self.selected: SessionTask | None = None
        self.last: tuple[str, TrialScore] | None = None  # (session id, score)
        self._spawn = spawn
        self._limiter = limiter
        self._scoring = 0
        self._chosen_file = None if recorder is None else recorder.store.root / CHOSEN_TASK_FILE
        if recorder is not None:
            recorder.session_end_hooks.append(self._on_session_end)
        self._load_choice()

    def _load_choice(self) -> None:
        """The task chosen before the station last stopped, if its scene still has it."""
        if self._chosen_file is None or not self._chosen_file.is_file():
            return
        try:
            saved = json.loads(self._chosen_file.read_text())
            if saved.get("scene") != self.scene.name:
                log.info(
                    "chosen task of scene %r not kept: the scene is now %r",
                    saved.get("scene"),
                    self.scene.name,
                )
                return
            self.select(saved["task_id"])
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            log.warning("chosen task in %s not used: %s", self._chosen_file, exc)

    def save_choice(self) -> None:
        """Blocking: keep the chosen task for the next start (written whole, then renamed)."""
        if self._chosen_file is None:
            return
        task_id = None if self.selected is None else self.selected.id
        try:
            write_json(self._chosen_file, {"scene": self.scene.name, "task_id": task_id})
        except OSError as exc:  # the choice still holds until the station stops
            log.error("cannot keep the chosen task in %s: %s", self._chosen_file, exc)

    def select(self, task_id: int | None) -> SessionTask | None:
        """Choose the task for the next sessions (None: no task); KeyError if unknown."""
        self.selected = (
            None
            if task_id is None
            else session_task(self.scene, self.scene_file, self.scene.task(task_id))
        )
        if self.recorder is not None:
            self.recorder.task = self.selected
        return self.selected

    @property
    def scoring(self) -> bool:
        return self._scoring > 0

    def _on_session_end(self, meta: SessionMeta, folder: Path) -> None:
        if meta.task is None:
            return
        self._scoring += 1
        self._spawn(f"score-{meta.id}", self._score(meta.id, meta.task, folder))

    async def _score(self, session_id: str, task: SessionTask, folder: Path) -> None:
        try:
            score = await anyio.to_thread.run_sync(
                score_and_store, folder, task, limiter=self._limiter
            )
            self.last = (session_id, score)
            log.info("session %s scored: %s", session_id, score.reason or "ok")
        finally:
            self._scoring -= 1

    async def attempts(self, task_id: int) -> list[dict[str, Any]]:
        """This UTC day's scored sessions of `task_id`, newest first."""
        if self.recorder is None:
            return []
        summaries = await asyncio.to_thread(self.recorder.store.list)
        today = dt.datetime.now(dt.UTC).date()
        out = []
        for s in summaries:
            m = s.meta
            if m is None or m.task is None or m.task.id != task_id or m.score is None:
                continue
            if (
                s.start_wall is None
                or dt.datetime.fromtimestamp(s.start_wall, dt.UTC).date() != today
            ):
                continue
            out.append({"session": s.id, "start_utc": m.start_utc, "score": public_score(m.score)})
            if len(out) >= MAX_ATTEMPTS_SHOWN:
                break
        return out

    @staticmethod
    def paper(analysis: str | None) -> dict[str, dict[str, float]] | None:
        """The paper's published figures for the task, physical and twin."""
        return PAPER_RESULTS.get(analysis) if analysis else None


def write_json(path: Path, data: Any) -> None:
    """Blocking: a small state file of the sessions folder, written whole then renamed
    (a reader never sees half of it); raises OSError."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


def station_scene(settings: Settings) -> tuple[Scene, Path | None, bool]:
    """The station's field, its file (None: the default field) and whether it is the
    field being flown (a scene file given, or the twin's), see the module docstring."""
    if settings.viser.field_file is not None:
        path = Path(settings.viser.field_file)
    elif settings.link.source.strip() == "sim" and settings.twin.scene is not None:
        path = Path(settings.twin.scene)
    elif settings.link.source.strip() == "sim":
        return load_scene(None), None, True
    else:
        return load_scene(None), None, False
    try:
        return load_scene(path), path, True
    except SceneError as exc:  # the station still flies; tasks come from the default field
        log.error("scene file not used: %s", exc)
        return load_scene(None), None, False
