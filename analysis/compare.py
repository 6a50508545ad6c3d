"""One table per task in the paper's layout (Tables 1-4: platform, then the task's metrics),
platform by platform, with the extras the paper lacks after them; as Markdown, CSV, JSON."""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass

from fpv_station.analysis.errors import AnalysisError
from fpv_station.analysis.tasks import TASK_TITLES, TaskResult

PLATFORM_NAMES = {"physical": "Physical quadcopter", "twin": "Digital twin"}
Column = tuple[str, str]  # (TaskResult field, heading)

PAPER_COLUMNS: dict[str, tuple[Column, ...]] = {
    "hover": (
        ("hover_distance_m", "Hovering distance to origin (m)"),
        ("height_deviation_m", "Height deviation (m)"),
        ("trial_time_s", "Trial time length (s)"),
    ),
}
_LONGITUDINAL: tuple[Column, ...] = (
    ("lateral_deviation_m", "Lateral deviation (m)"),
    ("height_deviation_m", "Height deviation (m)"),
    ("trial_time_s", "Trial time length (s)"),
)
EXTRA_COLUMNS: tuple[Column, ...] = (
    ("path_length_m", "Path length (m)"),
    ("mean_speed_mps", "Mean speed (m/s)"),
    ("max_speed_mps", "Max speed (m/s)"),
    ("time_in_window_s", "Time in window (s)"),
    ("obstacle_contacts", "Obstacle contacts"),
    ("landing_accuracy_m", "Landing accuracy (m)"),
    ("valid", "Valid"),
)
# The metrics where a smaller figure is the better flight (pages mark them).
LOWER_IS_BETTER = frozenset(
    {
        "hover_distance_m",
        "lateral_deviation_m",
        "height_deviation_m",
        "obstacle_contacts",
        "landing_accuracy_m",
    }
)


@dataclass(frozen=True)
class Comparison:
    task: str
    results: tuple[TaskResult, ...]

    @property
    def title(self) -> str:
        return f"{TASK_TITLES[self.task]}: flown trials on {len(self.results)} flight(s)"

    @property
    def columns(self) -> tuple[Column, ...]:
        return PAPER_COLUMNS.get(self.task, _LONGITUDINAL) + EXTRA_COLUMNS

    def headings(self) -> list[str]:
        return ["Platform used", "Session"] + [h for _, h in self.columns]

    def rows(self) -> list[list[str]]:
        return [
            [PLATFORM_NAMES.get(r.platform, r.platform), r.label]
            + [_fmt(getattr(r, name)) for name, _ in self.columns]
            for r in self.results
        ]

    def to_markdown(self) -> str:
        head = self.headings()
        lines = [f"**{self.title}**", "", "| " + " | ".join(head) + " |"]
        lines.append("| " + " | ".join(["---"] * 2 + ["---:"] * (len(head) - 2)) + " |")
        lines += ["| " + " | ".join(row) + " |" for row in self.rows()]
        lines += [""] + [
            f"- {r.label} is not valid: {'; '.join(r.invalid_reasons)}."
            for r in self.results
            if not r.valid
        ]
        lines += [
            f"- {r.label}, uncertain: {'; '.join(r.uncertain)}."
            for r in self.results
            if r.uncertain
        ]
        lower = [h for n, h in self.columns if n in LOWER_IS_BETTER]
        lines.append(f"Lower is better: {', '.join(lower)}.")
        return "\n".join(lines) + "\n"

    def to_csv(self) -> str:
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        w.writerow(["platform", "session"] + [name for name, _ in self.columns])
        for r in self.results:
            w.writerow([r.platform, r.label] + [_raw(getattr(r, n)) for n, _ in self.columns])
        return out.getvalue()

    def to_dict(self) -> dict:
        return {
            "task": self.task,
            "title": self.title,
            "columns": [
                {"field": n, "heading": h, "lower_is_better": n in LOWER_IS_BETTER}
                for n, h in self.columns
            ],
            "results": [r.to_dict() for r in self.results],
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)


def compare(results: list[TaskResult] | tuple[TaskResult, ...]) -> Comparison:
    if not results:
        raise AnalysisError("Nothing to compare: give at least one session.")
    tasks = {r.task for r in results}
    if len(tasks) != 1:
        raise AnalysisError(f"Compare sessions of one task at a time, not {sorted(tasks)}.")
    # The paper lists the physical quadcopter first, then the twin.
    ordered = sorted(results, key=lambda r: (r.platform != "physical", r.label))
    return Comparison(task=results[0].task, results=tuple(ordered))


def _fmt(value: object) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.3f}" if abs(value) < 100 else f"{value:.1f}"
    return str(value)


def _raw(value: object) -> str:
    return "" if value is None else (repr(value) if isinstance(value, float) else str(value))
