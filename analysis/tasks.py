"""The paper's four flight tasks: trial detection, analysis windows and metrics.

- Trial: from take-off to landing, detected from the armed state and the height (the
  vehicle is airborne while armed and more than `airborne_height_m` above the start,
  for at least `min_airborne_s`), not from the file's length. "Height" for deciding
  events is the pilot's altitude where recorded (`height_source`, see `frame`).
- Hover window: from the first time the height reaches `hover_height_m` (4 m) to
  `hover_window_s` (10 s) later.
- Other tasks' window: from the first time x is `margin_m` (2 m) past the take-off x to
  the last time it is still `margin_m` short of the landing x (distances along x, so a
  figure 8 that lands where it started works too).
- Metrics: hovering distance to origin = mean horizontal distance to the origin over the
  window; lateral deviation = std(y); height deviation = std(z) (population std,
  ddof=0, as numpy's default); trial time. Extras: path length (3D, over the trial),
  mean speed = path length / trial time, max speed over `speed_span_s` (1 s) baselines
  (GPS noise makes sample-to-sample speeds meaningless), time in window, and obstacle
  contacts when the field is known.
- Validity: a trial is `valid` unless the vehicle reported a crash during it, touched an
  obstacle, or landed off its landing pad; `invalid_reasons` says which, in words. A
  deviation measured on a crashed flight is not a result to set beside the paper's.
- Landing accuracy: horizontal distance from the landing point (where the vehicle sat
  when it disarmed, else its last airborne sample) to the centre of its landing pad (the
  session's task's end pad, else the pad nearest take-off for tasks that return, else
  the nearest other pad).
- Contacts and "off the pad" are judged for every flight on a known field, with a margin
  for the GPS's error (`gps_margin`): the receiver's recorded horizontal accuracy
  (GPS_RAW_INT `h_acc`) where the log has it, else `TaskParams.gps_accuracy_m` for a
  physical flight and none for the twin (its field is the one flown). A fault makes the
  trial invalid only when it holds wherever within the margin the vehicle truly was; one
  the GPS's error could undo (a pass that might have grazed an obstacle, a landing near
  the pad's edge) is named in `uncertain` instead, and the trial stays valid.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
from numpy.typing import NDArray

from fpv_station.analysis.errors import TaskWindowError, TooFewPointsError, UnknownTaskError
from fpv_station.analysis.field_layout import FieldLayout, Pad, obstacle_contacts
from fpv_station.analysis.flight_frame import AlignedTrack, HeightSource

Array = NDArray[np.float64]
TaskName = Literal["hover", "a-to-b", "obstacle", "figure8"]
TASKS: tuple[str, ...] = get_args(TaskName)
# Tasks that land where they took off; the others land on another pad.
RETURN_TASKS = frozenset({"hover", "figure8"})
TASK_TITLES = {
    "hover": "Task 1: Take off, hover, and land",
    "a-to-b": "Task 2: A to B",
    "obstacle": "Task 3: Obstacle avoidance",
    "figure8": "Task 4: Figure 8",
}


# The paper's published results (its Tables for tasks 1-4: the same pilot on the physical
# quadcopter and on the digital twin), to set a trial beside. Hover: distance from the
# origin; the others: lateral (std of y) and height (std of z) deviation; all in metres,
# trial time in seconds.
PAPER_RESULTS: dict[str, dict[str, dict[str, float]]] = {
    "hover": {
        "physical": {"hover_distance_m": 0.3691, "height_deviation_m": 0.0733, "trial_time_s": 63.4972},
        "twin": {"hover_distance_m": 0.1056, "height_deviation_m": 0.0693, "trial_time_s": 68.4444},
    },
    "a-to-b": {
        "physical": {"lateral_deviation_m": 0.6728, "height_deviation_m": 0.3654, "trial_time_s": 110.3442},
        "twin": {"lateral_deviation_m": 1.0038, "height_deviation_m": 0.0302, "trial_time_s": 87.5617},
    },
    "obstacle": {
        "physical": {"lateral_deviation_m": 2.3556, "height_deviation_m": 0.0648, "trial_time_s": 154.9210},
        "twin": {"lateral_deviation_m": 2.7866, "height_deviation_m": 0.3042, "trial_time_s": 104.0227},
    },
    "figure8": {
        "physical": {"lateral_deviation_m": 2.7589, "height_deviation_m": 0.1579, "trial_time_s": 232.8868},
        "twin": {"lateral_deviation_m": 2.4729, "height_deviation_m": 0.5843, "trial_time_s": 96.1778},
    },
}  # fmt: skip


@dataclass(frozen=True)
class TaskParams:
    """Every threshold of the method; the defaults are the paper's."""

    hover_height_m: float = 4.0
    hover_window_s: float = 10.0
    # "Reached 4 m" as height >= hover_height_m - tolerance. The paper: 4 m, no tolerance.
    # A pilot reading a 0.1 m display sees "4.0" from 3.95 m (tolerance 0.05), and a
    # controller that approaches from below may take seconds to cross the exact value.
    hover_height_tolerance_m: float = 0.0
    margin_m: float = 2.0
    airborne_height_m: float = 0.5
    min_airborne_s: float = 1.0  # shorter excursions (GPS altitude noise on the pad) ignored
    min_points: int = 10
    min_window_points: int = 3
    speed_span_s: float = 1.0
    vehicle_radius_m: float = 0.3  # F450: 450 mm motor-to-motor, props reach ~0.35 m
    # The GPS's horizontal error assumed for a physical flight whose log does not record
    # it (`h_acc`): a u-blox M8 receiver's stated 2.5 m (CEP), the paper's class of GPS.
    gps_accuracy_m: float = 2.5
    # What decides take-off, landing, reaching the hover height and obstacle contacts:
    # "pilot" = the altitude the pilot saw (since arming) where recorded, else GPS z;
    # "gps" = GPS z only. The deviations are always GPS z, as in the paper.
    height_source: HeightSource = "pilot"


@dataclass(frozen=True)
class Window:
    i0: int  # first sample index in the window
    i1: int  # last sample index in the window (inclusive)
    start_s: float
    end_s: float

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


@dataclass(frozen=True)
class TaskResult:
    task: str
    label: str
    platform: str  # "physical" or "twin"
    source: str
    trial_time_s: float
    takeoff_s: float
    landing_s: float
    window_start_s: float
    window_end_s: float
    time_in_window_s: float
    lateral_deviation_m: float
    height_deviation_m: float
    hover_distance_m: float | None  # hover task only
    path_length_m: float
    mean_speed_mps: float
    max_speed_mps: float
    obstacle_contacts: int | None  # None when the field's obstacles are unknown
    samples: int
    window_samples: int
    reference_kind: str
    origin_lat_deg: float
    origin_lon_deg: float
    origin_alt_m: float
    flight: int | None = None  # which flight of its file (1-based), when split into flights
    valid: bool = True  # False: crashed, touched an obstacle or landed off the pad
    invalid_reasons: tuple[str, ...] = ()  # why not valid, in words
    landing_pad: str | None = None  # the pad the trial should end on, when the field is known
    landing_accuracy_m: float | None = None  # landing point to that pad's centre (horizontal)
    # The GPS error allowed when judging contacts and the landing (median over the trial;
    # None: nothing judged), and the judgements that error could swing, in words.
    gps_margin_m: float | None = None
    uncertain: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        """As JSON gives it back (lists, not tuples)."""
        return {
            **dataclasses.asdict(self),
            "invalid_reasons": list(self.invalid_reasons),
            "uncertain": list(self.uncertain),
        }


def check_task(task: str) -> str:
    if task not in TASKS:
        raise UnknownTaskError(f"Unknown task '{task}'; use one of: {', '.join(TASKS)}.")
    return task


@dataclass(frozen=True)
class Landing:
    pad: str
    accuracy_m: float  # horizontal distance from the pad's centre
    on_pad: bool  # the vehicle (a disc of `vehicle_radius_m`) overlaps the pad's square
    margin_m: float = 0.0  # the GPS error allowed at the landing point
    uncertain: bool = False  # on or off the pad depends on where within the margin it was


def landing_index(a: AlignedTrack, i_land: int) -> int:
    """Where the vehicle came to rest: its last armed sample from the landing on (it
    disarmed there), else the sample after the last airborne one."""
    armed = np.flatnonzero(a.track.armed[i_land:])
    if armed.size:
        return i_land + int(armed[-1])
    return min(i_land + 1, len(a.track) - 1)


def landing(
    a: AlignedTrack,
    task: str,
    trial: tuple[int, int],
    p: TaskParams,
    pad_name: str | None,
    margin_m: Array | None = None,
) -> Landing | None:
    """The landing against the field's pad (see the module docstring); None without a
    field or pads. `margin_m`: the GPS error allowed at each sample (none: 0)."""
    field = a.field
    if field is None or not field.pads:
        return None
    i_to, i_land = trial
    i_rest = landing_index(a, i_land)
    at = a.xyz_m[i_rest, :2]
    pad = field.pad(pad_name) if pad_name else None
    if pad is None:
        pad = _expected_pad(field, task, a.xyz_m[i_to, :2], at)
    d = at - (pad.x_m, pad.y_m)
    # The pad's square is axis-aligned in the scene; the track frame is turned by
    # `rotation_rad`, so turn back into the pad's own axes.
    c, s = np.cos(-a.rotation_rad), np.sin(-a.rotation_rad)
    u, v = c * d[0] - s * d[1], s * d[0] + c * d[1]
    reach = pad.size_m / 2 + p.vehicle_radius_m
    off_by = max(abs(u), abs(v)) - reach  # > 0: off the pad's square
    m = float(margin_m[i_rest]) if margin_m is not None else 0.0
    return Landing(pad.name, float(np.hypot(*d)), bool(off_by <= 0), m, bool(abs(off_by) < m))


def _expected_pad(field: FieldLayout, task: str, takeoff_xy, landed_xy) -> Pad:
    def nearest(xy, pads) -> Pad:
        return min(pads, key=lambda q: float(np.hypot(q.x_m - xy[0], q.y_m - xy[1])))

    start = nearest(takeoff_xy, field.pads)
    if task in RETURN_TASKS or len(field.pads) == 1:
        return start
    return nearest(landed_xy, [q for q in field.pads if q is not start])


def invalid_reasons(
    crashes: Sequence[tuple[float | None, str]], contacts: int | None, land: Landing | None
) -> tuple[str, ...]:
    """Why a trial is not valid, in words (empty: valid). A landing whose side of the pad's
    edge the GPS's error could swing is no reason (`uncertain_judgements`)."""
    out = []
    for t_s, text in crashes[:1]:
        when = f" at {t_s:.1f} s" if t_s is not None else ""
        out.append(f"the vehicle reported a crash{when} ({text})")
    if contacts:
        out.append(f"it touched an obstacle ({contacts} contact{'s' if contacts > 1 else ''})")
    if land is not None and not land.on_pad and not land.uncertain:
        out.append(f"it landed off pad '{land.pad}', {land.accuracy_m:.1f} m from its centre")
    return tuple(out)


def uncertain_judgements(
    contacts: int | None, possible: int, margin_m: float, land: Landing | None
) -> tuple[str, ...]:
    """The judgements the GPS's error could swing, in words."""
    out = []
    if contacts is not None and possible > contacts:
        n = possible - contacts
        out.append(
            f"it may have touched an obstacle ({n} pass{'es' if n > 1 else ''} within the "
            f"GPS's {margin_m:.1f} m), not counted"
        )
    if land is not None and land.uncertain:
        side = "on" if land.on_pad else "off"
        out.append(
            f"it landed {land.accuracy_m:.1f} m from pad '{land.pad}''s centre, {side} the "
            f"pad by less than the GPS's {land.margin_m:.1f} m: on or off is not known"
        )
    return tuple(out)


def gps_margin(a: AlignedTrack, p: TaskParams) -> Array:
    """The GPS's horizontal error allowed at each sample when judging contacts and the
    landing: the recorded accuracy (`h_acc`) where the log has it, else
    `p.gps_accuracy_m` for a physical flight and 0 for the twin."""
    fallback = 0.0 if a.track.platform == "twin" else p.gps_accuracy_m
    h_acc = a.track.h_acc_m
    return np.where(np.isfinite(h_acc) & (h_acc > 0), h_acc, fallback)


def trial_span(a: AlignedTrack, p: TaskParams) -> tuple[int, int]:
    """Indices of take-off and landing (first and last airborne samples)."""
    airborne = a.height_m(p.height_source) > p.airborne_height_m
    if a.track.armed.any():  # without a heartbeat in the log, height alone decides
        airborne &= a.track.armed
    # Runs of consecutive airborne samples; a run must last `min_airborne_s` to count, so
    # GPS altitude wander while armed on the pad is not taken for a take-off.
    edges = np.diff(np.concatenate([[0], airborne.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    t = a.t_s
    keep = (t[ends] - t[starts]) >= p.min_airborne_s
    if not keep.any():
        raise TaskWindowError(
            f"'{a.label}': the vehicle never flew (never armed and more than "
            f"{p.airborne_height_m:g} m above the start for {p.min_airborne_s:g} s), so "
            "there is no trial to analyse."
        )
    return int(starts[keep][0]), int(ends[keep][-1])


def task_window(a: AlignedTrack, task: str, p: TaskParams, trial: tuple[int, int]) -> Window:
    t, x, z = a.t_s, a.xyz_m[:, 0], a.height_m(p.height_source)
    i_to, i_land = trial
    if task == "hover":
        target = p.hover_height_m - p.hover_height_tolerance_m
        reached = np.flatnonzero(z[i_to : i_land + 1] >= target)
        if reached.size == 0:
            raise TaskWindowError(
                f"'{a.label}': the vehicle never reached {target:g} m "
                f"(highest {np.max(z):.2f} m above the start); no hover window."
            )
        i0 = i_to + int(reached[0])
        t_end = t[i0] + p.hover_window_s
        if t_end > t[i_land]:
            raise TaskWindowError(
                f"'{a.label}': it landed {t[i_land] - t[i0]:.1f} s after reaching "
                f"{p.hover_height_m:g} m; the hover window needs {p.hover_window_s:g} s."
            )
        i1 = int(np.searchsorted(t, t_end, side="right")) - 1
    else:
        seg = slice(i_to, i_land + 1)
        past_start = np.flatnonzero(np.abs(x[seg] - x[i_to]) >= p.margin_m)
        short_of_end = np.flatnonzero(np.abs(x[seg] - x[i_land]) >= p.margin_m)
        if past_start.size == 0 or short_of_end.size == 0:
            raise TaskWindowError(
                f"'{a.label}': the vehicle never went {p.margin_m:g} m along x from "
                f"its take-off or landing point; no {task} window."
            )
        i0, i1 = i_to + int(past_start[0]), i_to + int(short_of_end[-1])
        if i1 <= i0:
            raise TaskWindowError(
                f"'{a.label}': it is never both {p.margin_m:g} m past the start and "
                f"{p.margin_m:g} m short of the end along x; no {task} window."
            )
    if i1 - i0 + 1 < p.min_window_points:
        raise TooFewPointsError(
            f"'{a.label}': only {i1 - i0 + 1} GPS samples in the {task} window."
        )
    return Window(i0=i0, i1=i1, start_s=float(t[i0]), end_s=float(t[i1]))


def analyze(
    a: AlignedTrack,
    task: str,
    params: TaskParams | None = None,
    judge_field: bool = True,
    crashes: Sequence[tuple[float | None, str]] = (),
    landing_pad: str | None = None,
) -> TaskResult:
    """The paper's metrics (and the extras) for one aligned flight, and whether the trial
    is valid. `crashes`: the vehicle's crash reports during this flight (session time,
    text). Obstacle contacts are counted, and a landing off the pad judged, when
    `judge_field` and the field is known (else contacts are None), within the GPS's
    error (`gps_margin`); `landing_pad` names the pad the trial should end on (else it is
    inferred, see the module docstring)."""
    p = params or TaskParams()
    check_task(task)
    trial = trial_span(a, p)
    w = task_window(a, task, p, trial)
    t, xyz = a.t_s, a.xyz_m
    win = xyz[w.i0 : w.i1 + 1]
    i_to, i_land = trial
    fly = xyz[i_to : i_land + 1]
    t_fly = t[i_to : i_land + 1]
    trial_s = float(t[i_land] - t[i_to])
    path_m = float(np.sum(np.linalg.norm(np.diff(fly, axis=0), axis=1)))
    contacts, possible = None, 0
    margin = gps_margin(a, p)
    if judge_field and a.field is not None and a.field.obstacles:
        body = fly.copy()
        body[:, 2] = a.height_m(p.height_source)[i_to : i_land + 1]
        m = margin[i_to : i_land + 1]
        contacts = obstacle_contacts(body, a.field.obstacles, p.vehicle_radius_m, m)
        possible = obstacle_contacts(body, a.field.obstacles, p.vehicle_radius_m, -m)
    land = landing(a, task, trial, p, landing_pad, margin)
    judged = land if judge_field else None
    reasons = invalid_reasons(crashes, contacts, judged)
    trial_margin = float(np.median(margin[i_to : i_land + 1]))
    unsure = uncertain_judgements(contacts, possible, trial_margin, judged)
    return TaskResult(
        task=task,
        label=a.label,
        platform=a.track.platform,
        source=a.track.source,
        trial_time_s=trial_s,
        takeoff_s=float(t[i_to]),
        landing_s=float(t[i_land]),
        window_start_s=w.start_s,
        window_end_s=w.end_s,
        time_in_window_s=w.duration_s,
        lateral_deviation_m=float(np.std(win[:, 1])),
        height_deviation_m=float(np.std(win[:, 2])),
        hover_distance_m=(
            float(np.mean(np.hypot(win[:, 0], win[:, 1]))) if task == "hover" else None
        ),
        path_length_m=path_m,
        mean_speed_mps=path_m / trial_s if trial_s > 0 else 0.0,
        max_speed_mps=_max_speed(t_fly, fly, p.speed_span_s),
        obstacle_contacts=contacts,
        samples=len(a.track),
        window_samples=w.i1 - w.i0 + 1,
        reference_kind=a.reference_kind,
        origin_lat_deg=a.origin[0],
        origin_lon_deg=a.origin[1],
        origin_alt_m=a.origin[2],
        valid=not reasons,
        invalid_reasons=reasons,
        landing_pad=land.pad if land else None,
        landing_accuracy_m=land.accuracy_m if land else None,
        gps_margin_m=trial_margin if judge_field and a.field is not None else None,
        uncertain=unsure,
    )


def _max_speed(t: np.ndarray, xyz: np.ndarray, span_s: float) -> float:
    """Largest speed between samples at least `span_s` apart (a 1 s baseline)."""
    j = np.searchsorted(t, t + span_s, side="left")
    ok = j < t.size
    if not ok.any():
        return float(np.linalg.norm(xyz[-1] - xyz[0]) / max(t[-1] - t[0], 1e-9))
    i = np.flatnonzero(ok)
    d = np.linalg.norm(xyz[j[ok]] - xyz[i], axis=1)
    return float(np.max(d / (t[j[ok]] - t[i])))
