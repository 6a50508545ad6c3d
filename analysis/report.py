"""From session paths to a finished analysis: load, align, measure, compare, and write the
table and figures. The CLI and the REST routes both call `analyze_tracks`, so they give
the same numbers.

One trial per flight: a file or session holding several take-off/landing cycles (several
sorties in one autopilot log, two flights joined by a post-disarm tail) is split into
flights (`analysis.flights`) and each is its own row, labelled "NAME flight N"; `flight`
picks one. A flight in which the task cannot be measured (a test hop in a file of
figure 8s) is listed in `skipped` with the reason, unless it is the only one asked for.

The field (pads and obstacles of the twin's scene) is used for a flight that starts
within `scene_radius_m` of one of its pads: its landing pad then gives the +x direction
(unless a reference is given), plots draw it, and every flight gets its obstacle
contacts counted and its landing judged on or off the pad, within the GPS's error
(`analysis.tasks.gps_margin`: a judgement that error could swing is named as uncertain,
not held against the trial). The vehicle's crash reports (its STATUSTEXTs: a session's messages.csv, as its
quality flags read them, or a bare tlog's own, through `open_recording`) make the flight
they fall in invalid, whichever file the flight was read from.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from fpv_station.analysis import plots
from fpv_station.analysis.compare import Comparison, compare
from fpv_station.analysis.errors import AnalysisError, TaskWindowError, TrackLoadError
from fpv_station.analysis.field_layout import FieldLayout, load_field_layout
from fpv_station.analysis.flight_frame import AlignedTrack, align_track
from fpv_station.analysis.flights import Flight, track_flights
from fpv_station.analysis.tasks import TaskParams, TaskResult, analyze, check_task
from fpv_station.analysis.track import Track, load_track
from fpv_station.companion.recording.flags import is_crash
from fpv_station.core.geodesy import geodetic_to_enu

SCENE_RADIUS_M = 150.0


@dataclass(frozen=True)
class Analysis:
    task: str
    aligned: tuple[AlignedTrack, ...]
    comparison: Comparison
    skipped: tuple[tuple[str, str], ...] = ()  # (label, why) of flights without a trial

    @property
    def results(self) -> tuple[TaskResult, ...]:
        return self.comparison.results

    def plot(self, kind: str) -> bytes:
        return plots.render(kind, self._ordered(), self.results)

    def _ordered(self) -> list[AlignedTrack]:
        by_source = {(a.track.source, a.label): a for a in self.aligned}
        return [by_source[(r.source, r.label)] for r in self.results]

    def to_dict(self) -> dict:
        """The comparison with the flights that have no trial: `skipped`, each with its
        label and why (the CLI's TABLE.json, the REST reply)."""
        skipped = [{"label": label, "reason": why} for label, why in self.skipped]
        return {**self.comparison.to_dict(), "skipped": skipped}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    def write(self, out_dir: Path) -> list[Path]:
        """Table as Markdown, CSV and JSON, and the three figures; returns the paths."""
        out_dir.mkdir(parents=True, exist_ok=True)
        prefix = self.task
        files = []
        for ext, text in (
            ("md", self.comparison.to_markdown()),
            ("csv", self.comparison.to_csv()),
            ("json", self.to_json()),
        ):
            path = out_dir / f"{prefix}_table.{ext}"
            path.write_text(text)
            files.append(path)
        return files + plots.write_all(self._ordered(), self.results, out_dir, prefix)


def field_for(
    track: Track, field: FieldLayout | None, radius_m: float = SCENE_RADIUS_M
) -> FieldLayout | None:
    """`field` if the track starts near one of its pads, else None."""
    if field is None or not field.pads or len(track) == 0:
        return None
    pads = np.array([[p.x_m, p.y_m] for p in field.pads])
    start = geodetic_to_enu(track.lat_deg[0], track.lon_deg[0], field.home[2], *field.home)
    return field if np.min(np.hypot(*(pads - start[:2]).T)) <= radius_m else None


def flight_tracks(track: Track, params: TaskParams, flight: int | None = None) -> list[Track]:
    """The track of each flight (or of flight number `flight`): its armed period with the
    ground time before it (back to the previous flight), where the flight frame finds its
    arming point. A track in which nothing flew is returned whole (its analysis says so)."""
    flights = track_flights(track, params.airborne_height_m, params.min_airborne_s)
    if flight is not None and not 1 <= flight <= len(flights):
        raise TaskWindowError(
            f"'{track.label}' has {len(flights)} flight(s); there is no flight {flight}."
        )
    if not flights:
        return [track]
    out = []
    for f in flights if flight is None else [flights[flight - 1]]:
        previous: Flight | None = flights[f.number - 2] if f.number > 1 else None
        start = previous.disarm + 1 if previous is not None else 0
        label = track.label if len(flights) == 1 else f"{track.label} flight {f.number}"
        part = track.select(slice(start, f.disarm + 1))
        out.append(replace(part, label=label, meta={**track.meta, "flight": f.number}))
    return out


def analyze_tracks(
    tracks: Sequence[Track],
    task: str,
    reference_latlon: tuple[float, float] | None = None,
    field: FieldLayout | None = None,
    params: TaskParams | None = None,
    flight: int | None = None,
) -> Analysis:
    """One row per flight of each track (`flight`: only that flight of each)."""
    check_task(task)
    p = params or TaskParams()
    aligned, results, skipped = [], [], []
    for whole in tracks:
        parts = flight_tracks(whole, p, flight)
        crashes = session_crashes(whole)
        starts = [float(part.t_s[0]) if len(part) else 0.0 for part in parts]
        for k, track in enumerate(parts):
            # A crash belongs to the flight it follows (the first flight: also any before).
            mine = [
                (t, text)
                for t, text in crashes
                if t is None
                or ((k == 0 or t >= starts[k]) and (k + 1 == len(parts) or t < starts[k + 1]))
            ]
            try:
                a, result = _analyze_one(track, task, reference_latlon, field, p, mine)
            except AnalysisError as exc:
                if len(parts) == 1 and len(tracks) == 1:
                    raise
                skipped.append((track.label, str(exc)))
                continue
            aligned.append(a)
            results.append(result)
    if not results:
        raise TaskWindowError(
            "No flight with a trial to analyse: " + "; ".join(f"{n}: {w}" for n, w in skipped)
        )
    return Analysis(
        task=task, aligned=tuple(aligned), comparison=compare(results), skipped=tuple(skipped)
    )


def session_crashes(track: Track) -> list[tuple[float | None, str]]:
    """The vehicle's crash reports in the recording a track was read from (session
    time, text): a folder's or a zip's messages.csv, or its tlog's STATUSTEXTs."""
    return [(t, text) for t, text in track.vehicle_texts if is_crash(text)]


def _landing_pad(meta: dict) -> str | None:
    task = meta.get("task")
    pad = task.get("end_pad") if isinstance(task, dict) else None
    return pad if isinstance(pad, str) else None


def _analyze_one(
    track: Track,
    task: str,
    reference_latlon: tuple[float, float] | None,
    field: FieldLayout | None,
    p: TaskParams,
    crashes: Sequence[tuple[float | None, str]] = (),
) -> tuple[AlignedTrack, TaskResult]:
    near = field_for(track, field)
    a = align_track(
        track,
        reference_latlon,
        near,
        min_points=p.min_points,
        min_reference_m=p.margin_m,
        ground_height_m=p.airborne_height_m,
    )
    result = analyze(a, task, p, True, crashes, _landing_pad(track.meta))
    return a, replace(result, flight=track.meta.get("flight"))


def analyze_paths(
    paths: Sequence[str | Path],
    task: str,
    reference_latlon: tuple[float, float] | None = None,
    scene: str | Path | None | bool = True,
    params: TaskParams | None = None,
    labels: Sequence[str] | None = None,
    flight: int | None = None,
) -> Analysis:
    """`scene`: True = the default field (core.scene.DEFAULT_SCENE), False = none, or a
    path to a scene file."""
    check_task(task)
    field = None if scene is False else load_field_layout(None if scene is True else scene)
    names = list(labels or [])
    tracks, skipped = [], []
    for i, path in enumerate(paths):
        name = names[i] if i < len(names) else None
        try:
            tracks.append(load_track(path, name))
        except TrackLoadError:
            raise  # not a recording: the user named the wrong thing
        except AnalysisError as exc:  # a recording without a measurable flight (no fix)
            if len(paths) == 1:
                raise
            skipped.append((name or Path(path).name, str(exc)))
    if not tracks:
        raise TaskWindowError(
            "No flight with a trial to analyse: " + "; ".join(f"{n}: {w}" for n, w in skipped)
        )
    analysis = analyze_tracks(tracks, task, reference_latlon, field, params, flight)
    return replace(analysis, skipped=(*skipped, *analysis.skipped))
