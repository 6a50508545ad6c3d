"""Policies flown in the twin (`TwinEnv`, seeded), scored with the paper's task metrics.

Each episode's true trajectory becomes an `analysis.track.Track` (the scene's ENU frame
placed on the Earth at the scene's home) and goes through the same `analysis` code as a
recorded session: trial, window, hover distance or lateral and height deviation, trial
time. On top of the paper's table:

- success: the task's analysis holds (a take-off, and for task 1 the 10 s hover at 4 m
  before the landing) and the flight ended landed (disarmed, no crash) on the target pad
  (within its square);
- crashes: episodes the twin ended with a crash;
- time: the episode's length (reset to landing, crash or the time limit).

Rows: the behaviour-cloning policy, the twin's scripted pilot, a uniformly random policy,
and the demonstrations (recorded sessions, scored the same way).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fpv_station.analysis.errors import AnalysisError
from fpv_station.analysis.field_layout import load_field_layout as load_field
from fpv_station.analysis.recording import open_recording
from fpv_station.analysis.report import analyze_tracks
from fpv_station.analysis.tasks import TaskParams, TaskResult
from fpv_station.analysis.track import Track, load_track
from fpv_station.core.geodesy import enu_to_geodetic
from fpv_station.core.scene import Scene, load_scene
from fpv_station.learn.episodes import COLUMNS
from fpv_station.learn.episodes import episodes as recording_episodes
from fpv_station.twin.gym_env import TwinEnv
from fpv_station.twin.pilot import Observation, Pilot, task_plan

TASK_NAMES = {1: "hover", 2: "a-to-b", 3: "obstacle", 4: "figure8"}
# The hover's "reached 4 m" tolerance: the scripted pilot levels off just under 4 m (see
# docs/ANALYSIS.md, "The twin flown by its scripted pilot"); every row uses the same.
PARAMS = TaskParams(hover_height_tolerance_m=0.05)
MAX_EPISODE_S = {1: 60.0, 2: 120.0, 3: 180.0, 4: 180.0}

Act = Callable[[np.ndarray, dict], np.ndarray]


@dataclass(frozen=True)
class Outcome:
    success: bool
    crashed: bool
    time_s: float
    result: TaskResult | None  # None when the task's analysis does not hold
    why: str = ""


@dataclass(frozen=True)
class Row:
    name: str
    outcomes: tuple[Outcome, ...]

    def mean(self, field: str) -> float:
        v = [getattr(o.result, field) for o in self.outcomes if o.result is not None]
        v = [x for x in v if x is not None]
        return float(np.mean(v)) if v else math.nan

    @property
    def success_rate(self) -> float:
        return sum(o.success for o in self.outcomes) / max(len(self.outcomes), 1)

    @property
    def crashes(self) -> int:
        return sum(o.crashed for o in self.outcomes)


def on_pad(scene: Scene, task_id: int, xy: np.ndarray) -> bool:
    pad = scene.pad(scene.task(task_id).end_pad)
    return bool(np.all(np.abs(np.asarray(xy) - pad.xy_m) <= pad.size_m / 2))


def fly_episode(act: Act, task_id: int, seed: int, scene: Scene | None = None) -> Outcome:
    """One seeded `TwinEnv` episode flown by `act(obs, info)`, scored."""
    scene = scene or load_scene()
    env = TwinEnv(task=task_id, scene=scene, max_episode_s=MAX_EPISODE_S.get(task_id, 180.0))
    obs, info = env.reset(seed=seed)
    t, pos, armed = [info["t_s"]], [info["pos_enu_m"]], [True]
    terminated = truncated = False
    while not (terminated or truncated):
        obs, _, terminated, truncated, info = env.step(act(obs, info))
        t.append(info["t_s"])
        pos.append(info["pos_enu_m"])
        armed.append(bool(env.sim.commander.armed[0]))
    crashed = bool(env.sim.state.crash[0])
    track = _track(scene, np.array(t), np.array(pos), np.array(armed), f"seed {seed}")
    result, why = _score(track, task_id)
    landed = terminated and not crashed
    success = result is not None and landed and on_pad(scene, task_id, pos[-1][:2])
    return Outcome(success, crashed, float(t[-1]), result, why)


def _track(scene: Scene, t, pos, armed, label: str) -> Track:
    h = scene.home
    llh = enu_to_geodetic(pos, h.lat_deg, h.lon_deg, h.alt_m)
    v = np.gradient(pos, t, axis=0) if len(t) > 1 else np.zeros_like(pos)
    return Track(
        label=label,
        source=label,
        t_s=t - t[0],
        wall_time=np.full(len(t), np.nan),
        lat_deg=llh[:, 0],
        lon_deg=llh[:, 1],
        alt_m=llh[:, 2],
        fix_type=np.full(len(t), 3, np.int16),
        armed=armed,
        relative_alt_m=pos[:, 2],
        ground_speed_mps=np.hypot(v[:, 0], v[:, 1]),
        climb_mps=v[:, 2],
        meta={"source": "twin"},
    )


def _score(track: Track, task_id: int) -> tuple[TaskResult | None, str]:
    try:
        a = analyze_tracks([track], TASK_NAMES[task_id], field=load_field(None), params=PARAMS)
    except AnalysisError as exc:
        return None, str(exc)
    return a.results[0], ""


# ---------------------------------------------------------------- the policies


def scripted_pilot(scene: Scene, task_id: int) -> Act:
    """The twin's scripted pilot, reading the env's observation (a fresh plan per reset:
    call this once per episode)."""
    pilot = Pilot(task_plan(scene, task_id))
    end = scene.pad(scene.task(task_id).end_pad)
    target = np.array([end.x_m, end.y_m, 0.0])

    def act(obs: np.ndarray, info: dict) -> np.ndarray:
        yaw = float(np.arctan2(obs[8], obs[9]))
        o = Observation(info["t_s"], obs[:3] + target, obs[3:6], yaw, obs[14] > 0.5)
        r, p, y, thr = pilot.update(o)
        return np.array([r, p, y, 2 * thr - 1], np.float32)

    return act


def random_policy(seed: int) -> Act:
    rng = np.random.default_rng(seed)
    return lambda obs, info: rng.uniform(-1, 1, 4).astype(np.float32)


def policy_act(policy) -> Act:
    return lambda obs, info: policy.act(obs, info["t_s"])


def evaluate(
    name: str, make_act: Callable[[int], Act], task_id: int, episodes: int, seed: int = 0
) -> Row:
    scene = load_scene()
    return Row(
        name,
        tuple(fly_episode(make_act(seed + k), task_id, seed + k, scene) for k in range(episodes)),
    )


def demonstrations(paths: Sequence[Path], task_id: int) -> Row:
    """Recorded sessions scored the same way (their flights' last frames say where they
    landed)."""
    scene = load_scene()
    outcomes = []
    for path in paths:
        with open_recording(path, COLUMNS) as rec:
            eps = list(recording_episodes(rec, scene, task_id, 10.0))
            crashed = str(rec.meta.get("stop_reason", "")).startswith("crash")
        track = load_track(path)
        result, why = _score(track, task_id)
        last = eps[-1] if eps else None
        landed = last is not None and last.landed and not crashed
        xy = last.state[-1, :2] + scene.pad(scene.task(task_id).end_pad).xy_m if last else None
        success = result is not None and landed and on_pad(scene, task_id, xy)
        time_s = last.duration_s if last else 0.0
        outcomes.append(Outcome(success, crashed, time_s, result, why))
    return Row("demonstrations", tuple(outcomes))


def table(rows: Sequence[Row], task_id: int) -> str:
    """The paper's table for the task, one row per policy, in Markdown."""
    hover = task_id == 1
    metrics = (
        [("hover distance (m)", "hover_distance_m")]
        if hover
        else [("lateral dev. (m)", "lateral_deviation_m")]
    )
    metrics += [("height dev. (m)", "height_deviation_m"), ("trial time (s)", "trial_time_s")]
    head = ["policy", "episodes", "success", "crashes", *(m[0] for m in metrics), "time (s)"]
    lines = [
        "| " + " | ".join(head) + " |",
        "| --- | " + " | ".join("---:" for _ in head[1:]) + " |",
    ]
    for r in rows:
        cells = [
            r.name,
            str(len(r.outcomes)),
            f"{r.success_rate:.0%}",
            str(r.crashes),
            *(_fmt(r.mean(f)) for _, f in metrics),
            _fmt(float(np.mean([o.time_s for o in r.outcomes])) if r.outcomes else math.nan),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _fmt(v: float) -> str:
    return "-" if math.isnan(v) else f"{v:.3f}"
