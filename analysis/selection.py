"""Sessions chosen for learning, by task, pilot and score: the one rule behind the
sessions page (`GET /api/selection`, `POST /api/exports`) and
`fpv-station export --select`.

A selection is written as comma-separated terms, the same text everywhere:

    task=1,pilot=Ana,kind=human,hover_distance_m<=0.3

- `task=N`: the flight task recorded in session.json (`task.id`);
- `pilot=NAME`: the demonstration's pilot (`demonstration.pilot`, case-insensitive;
  `scripted` for the twin's scripted pilot);
- `kind=human|scripted`: who flew it (`demonstration.kind`);
- `METRIC<=X`: a figure of the trial's score at most X (`METRICS`: the paper's
  deviations, the landing's distance from the pad, obstacle contacts, trial time).

Failed trials are left out unless `include_failed`: a trial counts only when the score the
station stored at the disarm (`analysis.trial_score`, session.json `score`) has a result
that is `valid` (no crash reported, no obstacle touched, landed on the pad). A session
with no score (no task chosen, not scored yet) has no such result and is left out too.
A session being recorded, or whose session.json cannot be read, is never selected.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from fpv_station.analysis.compare import LOWER_IS_BETTER
from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import PILOT_KINDS, SessionMeta, check_pilot_name
from fpv_station.companion.recording.store import SessionStore

METRICS = tuple(sorted(LOWER_IS_BETTER | {"trial_time_s"}))
MAX_TERMS = 16
_THRESHOLD = re.compile(r"\s*([a-z_]+)\s*<=\s*(\S+)\s*")


class SelectionError(ValueError):
    """A selection's text that says nothing valid; its message says what to write."""


@dataclass(frozen=True)
class Selection:
    task: int | None = None
    pilot: str | None = None
    kind: str | None = None
    at_most: tuple[tuple[str, float], ...] = ()  # (metric, threshold), in the text's order
    include_failed: bool = False

    @classmethod
    def parse(cls, text: str, include_failed: bool = False) -> Selection:
        """The selection `text` says (see the module docstring); SelectionError if it
        says something else."""
        terms = [t.strip() for t in (text or "").split(",") if t.strip()]
        if len(terms) > MAX_TERMS:
            raise SelectionError(f"a selection has at most {MAX_TERMS} terms")
        task = pilot = kind = None
        at_most: list[tuple[str, float]] = []
        for term in terms:
            m = _THRESHOLD.fullmatch(term)
            if m is not None:
                at_most.append((_metric(m.group(1)), _number(term, m.group(2))))
                continue
            key, eq, value = (p.strip() for p in term.partition("="))
            if not eq or not value:
                raise SelectionError(
                    f"'{term[:60]}': write task=N, pilot=NAME, kind=human|scripted or "
                    f"METRIC<=X, separated by commas"
                )
            if key == "task":
                if not re.fullmatch(r"[0-9]{1,6}", value):
                    raise SelectionError(f"'{term[:60]}': a task is its number (task=1)")
                task = int(value)
            elif key == "pilot":
                try:
                    pilot = check_pilot_name(value)
                except ValueError as exc:
                    raise SelectionError(str(exc)) from None
            elif key == "kind":
                if value not in PILOT_KINDS:
                    raise SelectionError(f"'{term[:60]}': kind is {' or '.join(PILOT_KINDS)}")
                kind = value
            else:
                raise SelectionError(
                    f"'{key[:40]}' is not a selection key; use task, pilot, kind or "
                    f"METRIC<=X ({', '.join(METRICS)})"
                )
        return cls(task, pilot, kind, tuple(at_most), include_failed)

    def text(self) -> str:
        """The selection written out (parses back to the same selection)."""
        terms = [f"task={self.task}"] if self.task is not None else []
        terms += [f"pilot={self.pilot}"] if self.pilot is not None else []
        terms += [f"kind={self.kind}"] if self.kind is not None else []
        terms += [f"{m}<={v:g}" for m, v in self.at_most]
        return ",".join(terms)

    def why_not(self, meta: SessionMeta | None) -> str | None:
        """Why the session is not selected, in words; None when it is."""
        if meta is None:
            return "its session.json cannot be read"
        if meta.status == layout.STATUS_RECORDING:
            return "it is being recorded"
        if self.task is not None and (meta.task is None or meta.task.id != self.task):
            return "another task" if meta.task is not None else "no task recorded"
        demo = meta.demonstration
        if self.pilot is not None and (
            demo is None or demo.pilot.casefold() != self.pilot.casefold()
        ):
            return "another pilot" if demo is not None else "not flown as a demonstration"
        if self.kind is not None and (demo is None or demo.kind != self.kind):
            return f"not flown by a {self.kind} pilot"
        failed = trial_failed(meta)
        if failed is not None and not self.include_failed:
            return failed
        result = (meta.score.result or {}) if meta.score is not None else {}
        for metric, limit in self.at_most:
            value = result.get(metric)
            if not isinstance(value, int | float) or math.isnan(value):
                return f"its score has no {metric}"
            if value > limit:
                return f"{metric} {value:.3g} over {limit:g}"
        return None


def trial_failed(meta: SessionMeta) -> str | None:
    """Why the session's trial does not count, from its stored score; None: it does."""
    score = meta.score
    if score is None:
        return "not scored" if meta.task is not None else "no task recorded, so no score"
    if not score.ok or score.result is None:
        return f"no score: {score.reason or 'the analysis did not hold'}"
    if score.result.get("valid") is not True:
        reasons = score.result.get("invalid_reasons") or ["not valid"]
        return "failed: " + "; ".join(str(r) for r in reasons)
    return None


@dataclass
class Chosen:
    """The sessions a selection took (ids, oldest first), and those only their failed
    trial kept out (id -> why), for a page or a CLI to say what it left out."""

    selection: Selection
    sessions: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)


def select_sessions(store: SessionStore, selection: Selection) -> Chosen:
    """Blocking: the sessions of `store` the selection takes (each session.json read)."""
    chosen = Chosen(selection)
    as_failed = Selection(selection.task, selection.pilot, selection.kind, (), True)
    for sid in store.ids():
        meta = store.meta_or_none(sid)
        why = selection.why_not(meta)
        if why is None:
            chosen.sessions.append(sid)
        elif meta is not None and as_failed.why_not(meta) is None:
            failed = trial_failed(meta)
            if failed is not None:
                chosen.failed[sid] = failed
    return chosen


def _metric(name: str) -> str:
    if name not in METRICS:
        raise SelectionError(
            f"'{name[:40]}' is not a score's figure; use one of {', '.join(METRICS)}"
        )
    return name


def _number(term: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise SelectionError(f"'{term[:60]}': the threshold is a number") from None
    if not math.isfinite(value):
        raise SelectionError(f"'{term[:60]}': the threshold is a finite number")
    return value
