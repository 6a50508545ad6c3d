"""What a user should know about a recorded session before trusting it: quality flags,
each with its reason in plain words, judged from session.json's quality report and what
the vehicle said (messages.csv).

The thresholds are here and only here (QUALITY_THRESHOLDS). They are what a pilot or an
analyst would call a problem, not any imperfection: one dropped frame in ten minutes is
not flagged; a twentieth of a camera's frames missing is.

  crash          the vehicle reported a crash (twin "CRASH: ...", ArduPilot "Crash: ...")
  failsafe       the vehicle reported a failsafe
  telemetry_gap  the autopilot was silent for longer than telemetry_gap_s (recorded by the
                 recorder as quality.telemetry_gaps; older sessions: their link-loss
                 intervals, which were at least link.link_lost_s long)
  link_loss      the link was lost (no autopilot message for link.link_lost_s) for more
                 than link_loss_pct of the session
  dropped_frames a camera lost more than dropped_frames_pct of the frames it captured
  telemetry_rows more than missing_rows_pct of the telemetry grid's rows are missing
                 (the writer was held up past the state history, or its queue was full)
"""

from __future__ import annotations

import csv
import dataclasses
import math
import re
from pathlib import Path

from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import LinkLoss, SessionMeta


@dataclasses.dataclass(frozen=True)
class QualityThresholds:
    telemetry_gap_s: float = 1.0
    link_loss_pct: float = 10.0
    dropped_frames_pct: float = 5.0
    missing_rows_pct: float = 5.0


QUALITY_THRESHOLDS = QualityThresholds()

_CRASH = re.compile(r"\bcrash", re.IGNORECASE)
_FAILSAFE = re.compile(r"fail-?safe", re.IGNORECASE)
_MESSAGES_READ_MAX = 1 << 20  # a vehicle that said more than 1 MB: the first MB decides


@dataclasses.dataclass(frozen=True)
class QualityFlag:
    kind: str  # crash, failsafe, telemetry_gap, link_loss, dropped_frames, telemetry_rows
    reason: str


def session_flags(
    meta: SessionMeta, folder: Path, t: QualityThresholds = QUALITY_THRESHOLDS
) -> list[QualityFlag]:
    """The flags of the session in `folder` (its session.json already read as `meta`)."""
    flags = _vehicle_flags(folder / layout.MESSAGES_CSV)
    q = meta.quality
    duration = meta.duration_s
    recorded = q.telemetry_gaps if "telemetry_gaps" in q.model_fields_set else q.link_loss
    lengths = [(g, _length(g, duration)) for g in recorded]
    gaps = [g for g, n in lengths if n is None or n > t.telemetry_gap_s]
    if gaps:
        longest = max(n or 0.0 for _, n in lengths)
        first = gaps[0].start_s
        flags.append(
            QualityFlag(
                "telemetry_gap",
                f"{len(gaps)} telemetry gap{'s' if len(gaps) > 1 else ''} over "
                f"{t.telemetry_gap_s:g} s (longest {longest:.1f} s, first at {first:.1f} s)",
            )
        )
    if duration:
        lost = sum(_length(iv, duration) or 0.0 for iv in q.link_loss)
        if 100 * lost / duration > t.link_loss_pct:
            flags.append(
                QualityFlag(
                    "link_loss",
                    f"link lost for {lost:.1f} s, {100 * lost / duration:.0f} % of the "
                    f"session (over {t.link_loss_pct:g} %)",
                )
            )
    for cam, cq in q.cameras.items():
        captured = max(cq.frames_captured, cq.frames_written + cq.frames_dropped)
        if captured and 100 * cq.frames_dropped / captured > t.dropped_frames_pct:
            flags.append(
                QualityFlag(
                    "dropped_frames",
                    f"{cam}: {cq.frames_dropped} of {captured} frames dropped, "
                    f"{100 * cq.frames_dropped / captured:.0f} % (over {t.dropped_frames_pct:g} %)",
                )
            )
    missing = q.telemetry_ticks_late + q.telemetry_rows_dropped
    expected = q.telemetry_rows + missing
    if expected and 100 * missing / expected > t.missing_rows_pct:
        flags.append(
            QualityFlag(
                "telemetry_rows",
                f"{missing} of {expected} telemetry rows missing, {100 * missing / expected:.0f} % "
                f"(over {t.missing_rows_pct:g} %)",
            )
        )
    return flags


def _length(iv: LinkLoss, duration_s: float | None) -> float | None:
    """An interval's length; one still open at the end runs to the session's end."""
    end = iv.end_s if iv.end_s is not None else duration_s
    return None if end is None else max(0.0, end - iv.start_s)


def vehicle_texts(path: Path) -> list[tuple[float | None, str]]:
    """The vehicle's STATUSTEXTs in a messages.csv: (session time or None, text)."""
    try:
        with open(path, newline="", encoding="utf-8", errors="replace") as f:
            text = f.read(_MESSAGES_READ_MAX)
    except OSError:
        return []
    out = []
    for row in csv.DictReader(text.splitlines()):
        if row.get("kind") != "statustext" or not row.get("text"):
            continue
        try:
            t_s: float | None = float(row.get("t_s") or "nan")
        except ValueError:
            t_s = None
        if t_s is not None and not math.isfinite(t_s):
            t_s = None
        out.append((t_s, row["text"].strip()))
    return out


def is_crash(text: str) -> bool:
    """Whether a vehicle's message reports a crash."""
    return _CRASH.search(text) is not None


def _vehicle_flags(path: Path) -> list[QualityFlag]:
    """Crash and failsafe, from the vehicle's STATUSTEXTs (the first of each is named)."""
    crash = failsafe = None
    for t_s, text in vehicle_texts(path):
        said = f"{text} (at {t_s:.1f} s)" if t_s is not None else text
        if crash is None and is_crash(text):
            crash = said
        if failsafe is None and _FAILSAFE.search(text):
            failsafe = said
    flags = []
    if crash is not None:
        flags.append(QualityFlag("crash", f"the vehicle said: {crash}"))
    if failsafe is not None:
        flags.append(QualityFlag("failsafe", f"the vehicle said: {failsafe}"))
    return flags
