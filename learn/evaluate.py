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

Each figure comes with a 95 % interval: Wilson's score interval for the success rate,
Student's t interval for the mean of each metric (over the episodes whose analysis holds).

Rows: the policy under evaluation (behaviour cloning, the vision policy flown from the
twin's bottom camera, `learn.vision`, or a policy trained by LeRobot,
`learn.lerobot_policy`, flown at its dataset's rate), the twin's scripted pilot, an
open-loop replay (a demonstration's recorded sticks replayed blind, frame by frame from
the arming: what a policy that ignores its observations scores), a uniformly random
policy, and the demonstrations (recorded sessions), a row for each kind of pilot that
flew them as session.json's `demonstration` says: human (per pilot when several),
scripted. A row's episodes (`EpisodeBatch`) fly together, one batch of
`TwinVectorEnv` seeded `seed`, and every flown row meets the same episodes (episode k
has the same wind, gusts, turbulence, start and sensor noise in every row), so rows are
compared pair by pair; what must differ is seeded apart (the random sticks per task and
episode). Each row says what it was scored on: flown rows the twin's true state, the
demonstrations their recorded GPS and barometer.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from fpv_station.analysis.errors import AnalysisError
from fpv_station.analysis.field_layout import load_field_layout as load_field
from fpv_station.analysis.recording import open_recording, recording_meta
from fpv_station.analysis.report import analyze_tracks
from fpv_station.analysis.tasks import TaskParams, TaskResult
from fpv_station.analysis.track import Track, load_track
from fpv_station.companion.recording.meta import PILOT_HUMAN, PILOT_KINDS, PILOT_SCRIPTED
from fpv_station.core.geodesy import enu_to_geodetic
from fpv_station.core.scene import Scene, load_scene
from fpv_station.learn.episodes import COLUMNS
from fpv_station.learn.episodes import episodes as recording_episodes
from fpv_station.twin.gym_vector import TwinVectorEnv
from fpv_station.twin.pilot import Observation, Pilot, task_plan

TASK_NAMES = {1: "hover", 2: "a-to-b", 3: "obstacle", 4: "figure8"}
# The hover's "reached 4 m" tolerance: the scripted pilot levels off just under 4 m (see
# docs/ANALYSIS.md, "The twin flown by its scripted pilot"); every row uses the same.
PARAMS = TaskParams(hover_height_tolerance_m=0.05)
MAX_EPISODE_S = {1: 60.0, 2: 120.0, 3: 180.0, 4: 180.0}
DEFAULT_EPISODES = 20
CONFIDENCE = 0.95
TRUE_STATE = "true state"
RECORDED = "recorded GPS + baro"
CONTROL_HZ = 10.0  # TwinEnv's default: one env step per recorded frame of a replay
_RANDOM_STREAM = 0x52414E44  # keeps the random sticks' draws apart from the env's seeds

Act = Callable[[np.ndarray, dict], np.ndarray]
# Every vehicle's sticks (n, 4) at once, from the batch's observations and info (`fly_batch`).
BatchAct = Callable[[np.ndarray, dict[str, Any]], np.ndarray]


@runtime_checkable
class BatchPolicy(Protocol):
    """A policy flown a batch at a time at its own rate (a LeRobot policy,
    `learn.lerobot_policy`): its row's name, `control_hz` (its dataset's fps) and, per
    batch, a `BatchAct` with a fresh state for `episodes` episodes."""

    name: str
    control_hz: float

    def batch_act(self, episodes: int) -> BatchAct: ...


@dataclass(frozen=True)
class Outcome:
    success: bool
    crashed: bool
    time_s: float
    result: TaskResult | None  # None when the task's analysis does not hold
    why: str = ""


@dataclass(frozen=True)
class EpisodeBatch:
    """The episodes a row is flown on, the same for every flown row: `episodes` episodes
    of task `task_id` flown together in one `TwinVectorEnv` batch seeded `seed` (episode k
    by the actor made for seed + k), reset with `options` (`air_options`; none: the
    scene's wind and start); an episode still flying at `max_episode_s` (none: the task's
    `MAX_EPISODE_S`) ends there."""

    task_id: int
    episodes: int = DEFAULT_EPISODES
    seed: int = 0
    options: dict[str, Any] | None = None
    max_episode_s: float | None = None


@dataclass(frozen=True)
class Row:
    name: str
    outcomes: tuple[Outcome, ...]
    scored_on: str = TRUE_STATE

    def values(self, field: str) -> np.ndarray:
        v = [getattr(o.result, field) for o in self.outcomes if o.result is not None]
        return np.array([x for x in v if x is not None], float)

    def mean(self, field: str) -> float:
        v = self.values(field)
        return float(np.mean(v)) if v.size else math.nan

    @property
    def successes(self) -> int:
        return sum(o.success for o in self.outcomes)

    @property
    def success_rate(self) -> float:
        return self.successes / max(len(self.outcomes), 1)

    @property
    def crashes(self) -> int:
        return sum(o.crashed for o in self.outcomes)


# ---------------------------------------------------------------- intervals


def _z(confidence: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(0.5 + confidence / 2))


def wilson_interval(k: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Wilson's score interval for a success rate of k in n (nan, nan for n = 0). Unlike
    p +- z sqrt(p (1 - p) / n) it stays within [0, 1] and is not empty at 0 or n."""
    if n <= 0:
        return math.nan, math.nan
    z = _z(confidence)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def mean_interval(
    values: Sequence[float] | np.ndarray, confidence: float = CONFIDENCE
) -> tuple[float, float]:
    """Student's t interval for the mean of `values` (nan, nan for fewer than two)."""
    from scipy.stats import t

    v = np.asarray(values, float)
    if v.size < 2:
        return math.nan, math.nan
    half = float(t.ppf(0.5 + confidence / 2, v.size - 1)) * v.std(ddof=1) / math.sqrt(v.size)
    m = float(v.mean())
    return m - half, m + half


def difference_interval(
    k1: int, n1: int, k2: int, n2: int, confidence: float = CONFIDENCE
) -> tuple[float, float, float]:
    """(p1 - p2, low, high): Newcombe's hybrid score interval for the difference of two
    success rates, from the two Wilson intervals."""
    p1, p2 = k1 / n1, k2 / n2
    l1, u1 = wilson_interval(k1, n1, confidence)
    l2, u2 = wilson_interval(k2, n2, confidence)
    d = p1 - p2
    return (
        d,
        d - math.sqrt((p1 - l1) ** 2 + (u2 - p2) ** 2),
        d + math.sqrt((u1 - p1) ** 2 + (p2 - l2) ** 2),
    )


def on_pad(scene: Scene, task_id: int, xy: np.ndarray) -> bool:
    pad = scene.pad(scene.task(task_id).end_pad)
    return bool(np.all(np.abs(np.asarray(xy) - pad.xy_m) <= pad.size_m / 2))


def fly_episodes(
    acts: Sequence[Act],
    batch: EpisodeBatch,
    control_hz: float = CONTROL_HZ,
    scene: Scene | None = None,
) -> tuple[Outcome, ...]:
    """Episode k of `batch` flown by `acts[k](obs, info)` (info: "t_s", "pos_enu_m"), all
    together (`fly_batch`): one actor per episode."""
    if len(acts) != batch.episodes:
        raise ValueError(f"{len(acts)} actors for a batch of {batch.episodes} episodes")
    idle = np.zeros(4, np.float32)

    def act(obs: np.ndarray, info: dict[str, Any]) -> np.ndarray:
        return np.stack(
            [
                idle
                if info["done"][k]
                else acts[k](obs[k], {"t_s": info["t_s"][k], "pos_enu_m": info["pos_enu_m"][k]})
                for k in range(len(acts))
            ]
        )

    return fly_batch(act, batch, control_hz, scene)


def fly_batch(
    act: BatchAct,
    batch: EpisodeBatch,
    control_hz: float = CONTROL_HZ,
    scene: Scene | None = None,
) -> tuple[Outcome, ...]:
    """`batch`'s episodes flown together in one `TwinVectorEnv` (no autoreset: vehicle
    k's air, start and sensor noise are the same whatever flies it), stepped at
    `control_hz`, each scored. Each step, `act(obs, info)` gives every vehicle's sticks
    (n, 4) from the observations (n, 18) and info: "t_s" (n,) since arming, "pos_enu_m"
    (n, 3), "done" (n,) (an ended vehicle's sticks are ignored) and "pose" (`pose(k)`:
    vehicle k's true pose, what its cameras see from)."""
    scene = scene or load_scene()
    task_id, seed, n = batch.task_id, batch.seed, batch.episodes
    env = TwinVectorEnv(
        num_envs=n,
        task=task_id,
        scene=scene,
        max_episode_s=batch.max_episode_s or MAX_EPISODE_S.get(task_id, 180.0),
        control_hz=control_hz,
        autoreset=False,
    )
    obs, _ = env.reset(seed=seed, options=batch.options)
    t_s = np.zeros(n)
    t, pos, armed = [t_s], [env.sim.state.pos_m.copy()], [env.sim.commander.armed.copy()]
    done = np.zeros(n, bool)
    end = np.zeros(n, int)  # the step each episode ended at
    landed = np.zeros(n, bool)  # ... disarmed on the ground (terminated, no crash)
    crashed = np.zeros(n, bool)
    while not done.all():
        info = {"t_s": t_s, "pos_enu_m": pos[-1], "done": done.copy(), "pose": env.sim.pose}
        actions = np.where(done[:, None], 0.0, np.asarray(act(obs, info), np.float32))
        obs, _, terminated, truncated, info = env.step(actions)
        t_s = info["t_s"]
        t.append(t_s)
        pos.append(env.sim.state.pos_m.copy())
        armed.append(env.sim.commander.armed.copy())
        new = (terminated | truncated) & ~done
        end[new] = len(t) - 1
        crashed[new] = env.sim.state.crash[new] != 0
        landed[new] = terminated[new] & ~crashed[new]
        done |= new
    T, P, A = np.array(t), np.array(pos), np.array(armed)
    outcomes = []
    for k in range(n):
        e = end[k]
        label = f"seed {seed}, episode {k}"
        track = _track(scene, T[: e + 1, k], P[: e + 1, k], A[: e + 1, k], label)
        result, why = _score(track, task_id)
        success = result is not None and landed[k] and on_pad(scene, task_id, P[e, k, :2])
        outcomes.append(Outcome(bool(success), bool(crashed[k]), float(T[e, k]), result, why))
    return tuple(outcomes)


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


def random_policy(seed: int, task_id: int = 0) -> Act:
    """Uniform sticks, seeded by the episode and the task: tasks that start alike (3 and 4)
    do not get the same flight."""
    rng = np.random.default_rng([seed, task_id, _RANDOM_STREAM])
    return lambda obs, info: rng.uniform(-1, 1, 4).astype(np.float32)


def open_loop(sticks: np.ndarray) -> Act:
    """Recorded sticks (T, 4), one per env step from the arming, ignoring every
    observation; after the last, the last is held."""
    sticks = np.asarray(sticks, np.float32)
    if not len(sticks):
        raise ValueError("an open-loop replay needs at least one recorded stick")
    step = itertools.count()

    def act(obs: np.ndarray, info: dict) -> np.ndarray:
        return sticks[min(next(step), len(sticks) - 1)]

    return act


def recorded_sticks(paths: Sequence[Path], task_id: int, fps: float) -> list[np.ndarray]:
    """Each demonstration flight's sticks at `fps` (the env's control rate), from the
    arming: the episodes `export` makes, read by the same code."""
    scene = load_scene()
    out = []
    for path in paths:
        with open_recording(path, COLUMNS) as rec:
            out += [ep.action for ep in recording_episodes(rec, scene, task_id, fps)]
    return out


def policy_act(policy, scene: Scene | None = None) -> Act:
    """A trained policy as an actor: a state policy's `act(state, t_s)`; a policy that
    flies from a camera makes its own actor that renders the twin's picture (`twin_act`)."""
    if hasattr(policy, "twin_act"):
        return policy.twin_act(scene or load_scene())
    return lambda obs, info: policy.act(obs, info["t_s"])


def evaluate(name: str, make_act: Callable[[int], Act], batch: EpisodeBatch) -> Row:
    """`batch` flown (`fly_episodes`), episode k by `make_act(batch.seed + k)`."""
    acts = [make_act(batch.seed + k) for k in range(batch.episodes)]
    return Row(name, fly_episodes(acts, batch, CONTROL_HZ, load_scene()))


def policy_row(policy, batch: EpisodeBatch) -> Row:
    """The row of the policy under evaluation: a `BatchPolicy` flown a batch at a time at
    its rate, else per episode (`policy_act`: behaviour cloning, or the vision policy
    under its `row_name`)."""
    if isinstance(policy, BatchPolicy):
        act = policy.batch_act(batch.episodes)
        return Row(policy.name, fly_batch(act, batch, policy.control_hz, load_scene()))
    name = getattr(policy, "row_name", "behaviour cloning")
    return evaluate(name, lambda s: policy_act(policy), batch)


def demonstrations(paths: Sequence[Path], task_id: int, name: str = "demonstrations") -> Row:
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
        success = result is not None and landed and xy is not None and on_pad(scene, task_id, xy)
        time_s = last.duration_s if last else 0.0
        outcomes.append(Outcome(success, crashed, time_s, result, why))
    return Row(name, tuple(outcomes), RECORDED)


def demonstration_rows(paths: Sequence[Path], task_id: int) -> list[Row]:
    """The recorded sessions' rows, by who flew them (session.json `demonstration`):
    "human demonstrations" (one row per pilot, "human demonstrations (NAME)", when
    several flew), "scripted demonstrations", and "demonstrations" for sessions that do
    not say; in that order."""
    groups: dict[tuple[str, str], list[Path]] = {}
    for path in paths:
        said = recording_meta(path).get("demonstration")
        demo = said if isinstance(said, dict) else {}
        kind = demo.get("kind")
        pilot = str(demo.get("pilot", "")) if kind == PILOT_HUMAN else ""
        groups.setdefault((kind if kind in PILOT_KINDS else "", pilot), []).append(Path(path))
    pilots = {p for k, p in groups if k == PILOT_HUMAN}
    order = {PILOT_HUMAN: 0, PILOT_SCRIPTED: 1, "": 2}
    rows = []
    for kind, pilot in sorted(groups, key=lambda g: (order[g[0]], g[1].casefold())):
        name = f"{kind} demonstrations" if kind else "demonstrations"
        if kind == PILOT_HUMAN and len(pilots) > 1:
            name += f" ({pilot})"
        rows.append(demonstrations(groups[kind, pilot], task_id, name))
    return rows


def table(rows: Sequence[Row], task_id: int, confidence: float = CONFIDENCE) -> str:
    """The paper's table for the task, one row per policy, in Markdown: each figure with
    its interval in brackets (a metric's mean over fewer episodes than the row's says
    over how many)."""
    hover = task_id == 1
    metrics = (
        [("hover distance (m)", "hover_distance_m")]
        if hover
        else [("lateral dev. (m)", "lateral_deviation_m")]
    )
    metrics += [("height dev. (m)", "height_deviation_m"), ("trial time (s)", "trial_time_s")]
    pct = f"{confidence:.0%}"
    head = [
        "policy",
        "scored on",
        "episodes",
        f"success [{pct}]",
        "crashes",
        *(f"{m[0]} [{pct}]" for m in metrics),
        "time (s)",
    ]
    lines = [
        "| " + " | ".join(head) + " |",
        "| --- | --- | " + " | ".join("---:" for _ in head[2:]) + " |",
    ]
    for r in rows:
        n = len(r.outcomes)
        lo, hi = wilson_interval(r.successes, n, confidence)
        success = f"{r.success_rate:.0%} [{lo:.0%}, {hi:.0%}]" if n else "-"
        cells = [
            r.name,
            r.scored_on,
            str(n),
            success,
            str(r.crashes),
            *(_metric(r.values(f), n, confidence) for _, f in metrics),
            _fmt(float(np.mean([o.time_s for o in r.outcomes])) if r.outcomes else math.nan),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def compare(a: Row, b: Row, confidence: float = CONFIDENCE) -> str:
    """One line: a's success rate minus b's, with its interval, and whether a beats b by
    more than the interval (its lower end above zero)."""
    if not a.outcomes or not b.outcomes:
        return f"{a.name} vs {b.name}: no episodes to compare"
    d, lo, hi = difference_interval(
        a.successes, len(a.outcomes), b.successes, len(b.outcomes), confidence
    )
    verdict = "beats" if lo > 0 else "does not beat"
    return (
        f"{a.name} - {b.name}, success: {d:+.0%} [{lo:+.0%}, {hi:+.0%}] "
        f"({confidence:.0%}, Newcombe): {a.name} {verdict} {b.name}"
    )


def _metric(v: np.ndarray, n: int, confidence: float) -> str:
    if not v.size:
        return "-"
    lo, hi = mean_interval(v, confidence)
    cell = f"{v.mean():.3f}" + (f" [{lo:.3f}, {hi:.3f}]" if v.size > 1 else "")
    return cell + (f" (n={v.size})" if v.size < n else "")


def _fmt(v: float) -> str:
    return "-" if math.isnan(v) else f"{v:.3f}"


def air_options(
    wind_enu_mps: tuple[float, float] = (0.0, 0.0),
    gust_std_mps: float = 0.0,
    turbulence_std_mps: float = 0.0,
    random_start_deg: float | None = None,
) -> dict[str, Any]:
    """`TwinEnv` reset options for a wind (mean east, north; gusts; turbulence) and, with
    `random_start_deg`, a random start on the pad within that many degrees of east. Calm
    and a fixed start give no options: the scene's."""
    options: dict[str, Any] = {}
    if any(wind_enu_mps) or gust_std_mps or turbulence_std_mps:
        options["wind"] = {
            "mean_enu_mps": [float(wind_enu_mps[0]), float(wind_enu_mps[1]), 0.0],
            "gust_std_mps": float(gust_std_mps),
            "turbulence_std_mps": float(turbulence_std_mps),
        }
    if random_start_deg is not None:
        options["start"] = {"random": True, "heading_deg": float(random_start_deg)}
    return options


def benchmark(
    policy, batch: EpisodeBatch, demos: Sequence[Path] = (), baselines: bool = True
) -> list[Row]:
    """The rows of `learn eval`: the policy (`policy_row`), then (with `baselines`) the
    scripted pilot, the open-loop replay of `demos` (episode k replays flight k mod their
    count) and random sticks, then the demonstrations (by who flew them,
    `demonstration_rows`); all flown rows on the same episodes, `batch`."""
    scene = load_scene()
    task_id, seed = batch.task_id, batch.seed
    rows = [policy_row(policy, batch)]
    if baselines:
        rows.append(evaluate("scripted pilot", lambda s: scripted_pilot(scene, task_id), batch))
    sticks = recorded_sticks(demos, task_id, CONTROL_HZ) if demos else []
    if baselines and sticks:
        rows.append(
            evaluate(
                "open-loop replay", lambda s: open_loop(sticks[(s - seed) % len(sticks)]), batch
            )
        )
    if baselines:
        rows.append(evaluate("random", lambda s: random_policy(s, task_id), batch))
    if demos:
        rows += demonstration_rows(demos, task_id)
    return rows
