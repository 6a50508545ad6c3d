"""The one score of a flown trial: the task's analysis of a finished session, stored in
its session.json (`score`).

The station scores each session with a task when the vehicle disarms (server.trials), the
twin's scripted demonstrations when they land (learn.demos); both call `score_and_store`,
the same call as `fpv-station analyze --task T SESSION [--scene FILE]`. The score says
whether the trial is `valid` (no crash, no obstacle touched, landed on the pad): what a
selection of sessions for learning leaves out (analysis.selection).
"""

from __future__ import annotations

import datetime as dt
import logging
from pathlib import Path

from fpv_station.analysis.errors import AnalysisError, without_dirs
from fpv_station.analysis.report import analyze_paths
from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import SessionTask, TrialScore, read_meta, write_meta

log = logging.getLogger(__name__)


def score_session(folder: Path, task: SessionTask) -> TrialScore:
    """Blocking: the task's analysis of one finished session, as `fpv-station analyze`."""
    now = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
    if task.analysis is None:
        return TrialScore(task="none", ok=False, reason="This task has no scoring.", scored_utc=now)
    scene = Path(task.scene_file) if task.scene_file else True
    try:
        analysis = analyze_paths([folder], task.analysis, scene=scene)
    except AnalysisError as exc:  # never reached the window, no GPS fix, too short ...
        reason = without_dirs(str(exc))
        return TrialScore(task=task.analysis, ok=False, reason=reason, scored_utc=now)
    result = {**analysis.results[0].to_dict(), "source": folder.name}
    return TrialScore(task=task.analysis, ok=True, scored_utc=now, result=result)


def score_and_store(folder: Path, task: SessionTask) -> TrialScore:
    """Blocking: `score_session`, amended into the session's session.json."""
    score = score_session(folder, task)
    path = folder / layout.SESSION_JSON
    try:
        meta = read_meta(path)
        write_meta(path, meta.model_copy(update={"score": score}))
    except (OSError, ValueError) as exc:  # the score is still returned (and shown)
        log.error("cannot store the score in %s: %s", path, exc)
    return score
