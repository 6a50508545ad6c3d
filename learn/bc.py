"""Behaviour cloning: a small policy from the state (and the time since arming) to the
pilot's four sticks, trained on a LeRobot dataset exported by `fpv-station export`.

The model is scikit-learn's k-nearest-neighbours regressor (distance-weighted mean of
the `k` closest demonstrated frames' sticks). It is CPU-only, has nothing to tune but
`k`, and needs no torch. Inputs, each divided by a fixed physical scale (`SCALES`) so
that distances mean the same in every dataset: the position relative to the target, the
heading, on the ground, and the time since arming (the state alone cannot say when a
timed phase is over: task 1 holds the hover for 10 s, then lands; a demonstration's
`timestamp` is that time, `TwinEnv` reports it as `info["t_s"]`).

Left out, on purpose: velocities and attitude. With them the clone copies itself: a
vehicle cruising at 1.4 m/s finds its neighbours among cruising frames and flew past
the task 2 pad into the net; the scripted pilots command speed from the distance to go,
which position alone carries. Also out: body rates, battery, armed (constant), and the
distances the position repeats. Standardizing by the data's spread instead blew sensor
noise on nearly constant inputs up into the distance (a 4-demo policy never took off).

A policy file is an `.npz` of plain arrays (the training inputs and sticks, the scales,
`k`): no pickle, so loading a policy file runs no code from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
from numpy.typing import NDArray

from fpv_station.learn.lerobot import read_meta

FORMAT = "fpv-station-bc-knn-2"
DEFAULT_K = 5
# The state elements the policy reads (`twin.gym_env.STATE_NAMES`): x, y, z to the
# target, sin and cos of the heading, on the ground; then the time since arming.
FEATURES = (0, 1, 2, 8, 9, 15)
# What one unit of distance is, per input: 1 m along the ground, 0.5 m in height, 0.2 of
# heading sine/cosine (~12 degrees), on/off the ground, 2 s.
SCALES = (1.0, 1.0, 0.5, 0.2, 0.2, 1.0, 2.0)


@dataclass
class BcPolicy:
    inputs: NDArray[np.float32]  # (n, len(FEATURES) + 1): state features, seconds since arming
    sticks: NDArray[np.float32]  # (n, 4)
    k: int = DEFAULT_K
    task_id: int = 0  # the task of the demonstrations (0 = unknown)

    def __post_init__(self) -> None:
        self._model = Neighbours(self.inputs, self.sticks, self.k, SCALES)

    def act(self, state: np.ndarray, t_s: float) -> np.ndarray:
        return self._model.sticks(np.append(np.asarray(state, np.float64)[list(FEATURES)], t_s))

    def save(self, path: Path) -> Path:
        return save_arrays(
            path,
            FORMAT,
            features=np.array(FEATURES),
            scales=np.array(SCALES),
            inputs=self.inputs,
            sticks=self.sticks,
            k=np.array(self.k),
            task_id=np.array(self.task_id),
        )

    @classmethod
    def load(cls, path: Path) -> BcPolicy:
        z = load_arrays(path, FORMAT, "behaviour-cloning policy", ("features", "scales"))
        if tuple(z["features"].tolist()) != FEATURES or tuple(z["scales"].tolist()) != SCALES:
            raise ValueError(f"'{path}' reads other state features; train it again")
        return cls(inputs=z["inputs"], sticks=z["sticks"], k=int(z["k"]), task_id=int(z["task_id"]))


class Neighbours:
    """The learner: scikit-learn's k-nearest-neighbours regressor, distance weighted, over
    inputs divided by fixed physical scales; sticks clipped to [-1, 1]."""

    def __init__(self, inputs: np.ndarray, sticks: np.ndarray, k: int, scales) -> None:
        from sklearn.neighbors import KNeighborsRegressor

        self._scale = np.asarray(scales, np.float64)
        self._model = KNeighborsRegressor(n_neighbors=min(k, len(inputs)), weights="distance")
        self._model.fit(inputs / self._scale, sticks)

    def sticks(self, x: np.ndarray) -> np.ndarray:
        a = self._model.predict((np.asarray(x, np.float64) / self._scale)[None, :])[0]
        return np.clip(a, -1.0, 1.0).astype(np.float32)


def save_arrays(path: Path, fmt: str, **arrays: np.ndarray) -> Path:
    """A policy file: `arrays`, `k`, `task_id` and the `format` tag in one .npz."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:  # a file object: numpy would append ".npz" to a name
        np.savez_compressed(f, allow_pickle=True, format=np.array(fmt), **arrays)
    return path


def load_arrays(path: Path, fmt: str, what: str, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """A policy file's arrays, read with no pickle (loading runs no code from the file):
    it must carry the `format` tag `fmt` and the arrays `names` besides the inputs, sticks,
    `k` and `task_id`."""
    with np.load(Path(path), allow_pickle=False) as z:
        if "format" not in z or str(z["format"]) != fmt:
            raise ValueError(f"'{path}' is not an fpv-station {what}")
        missing = {"inputs", "sticks", "k", "task_id", *names} - set(z.files)
        if missing:
            raise ValueError(f"'{path}' has no {', '.join(sorted(missing))}; train it again")
        return {name: z[name] for name in z.files}


@dataclass(frozen=True)
class Rows:
    """Every frame of a LeRobot dataset from `export`, in the data files' order."""

    state: np.ndarray  # (n, STATE_SIZE) `observation.state`
    action: np.ndarray  # (n, 4) sticks
    t_s: np.ndarray  # (n,) `timestamp`: seconds since the episode's first frame
    episode: np.ndarray  # (n,) `episode_index`
    task_id: int  # the task of the demonstrations (0 = unknown)


def read_rows(root: Path) -> Rows:
    """The frames of a LeRobot dataset from `export` (its data files and task)."""
    root = Path(root)
    files = sorted((root / "data").glob("*/*.parquet"))
    if not files:
        raise ValueError(f"'{root}' is not a LeRobot dataset (no data/*/*.parquet)")
    cols = ["observation.state", "action", "timestamp", "episode_index"]
    tables = [pq.read_table(f, columns=cols) for f in files]
    return Rows(
        state=np.concatenate([_matrix(t.column("observation.state")) for t in tables]),
        action=np.concatenate([_matrix(t.column("action")) for t in tables]).astype(np.float32),
        t_s=np.concatenate([t.column("timestamp").to_numpy() for t in tables]),
        episode=np.concatenate([t.column("episode_index").to_numpy() for t in tables]),
        task_id=read_meta(root).task_id,
    )


def read_lerobot(root: Path) -> tuple[np.ndarray, np.ndarray, int]:
    """(inputs, sticks, task_id) of every frame of a LeRobot dataset from `export`."""
    r = read_rows(root)
    inputs = np.column_stack([r.state[:, list(FEATURES)], r.t_s]).astype(np.float32)
    return inputs, r.action, r.task_id


def train(dataset: Path, k: int = DEFAULT_K) -> BcPolicy:
    inputs, sticks, task_id = read_lerobot(dataset)
    if len(inputs) < 2:
        raise ValueError(f"'{dataset}' has {len(inputs)} frames; behaviour cloning needs more")
    return BcPolicy(inputs, sticks, k, task_id)


def _matrix(col) -> np.ndarray:
    """A fixed-size-list column as an (n, size) array, without a Python loop."""
    arr = col.combine_chunks()
    return arr.values.to_numpy(zero_copy_only=False).reshape(len(arr), arr.type.list_size)
