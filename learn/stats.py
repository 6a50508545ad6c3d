"""Feature statistics as LeRobot keeps them (min, max, mean, std, count and the q01, q10,
q50, q90, q99 quantiles), per episode and merged over a dataset.

Vectors are reduced over frames (one value per element); images over frames and pixels,
per channel, scaled to [0, 1] and shaped (3, 1, 1) as LeRobot's image stats are.
Merging follows LeRobot's rule: means weighted by count, variances pooled about the
merged mean, extremes of extremes, and quantiles as count-weighted means (an
approximation LeRobot makes too: exact quantiles would need every value).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

QUANTILES = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}

Stats = dict[str, NDArray[np.float64]]


def vector_stats(values: NDArray) -> Stats:
    """Stats of (n, ...) values over the first axis."""
    v = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
    out = {
        "min": v.min(0),
        "max": v.max(0),
        "mean": v.mean(0),
        "std": v.std(0),
        "count": np.array([v.shape[0]], dtype=np.float64),
    }
    q = np.quantile(v, list(QUANTILES.values()), axis=0)
    out.update({k: q[i] for i, k in enumerate(QUANTILES)})
    return out


def image_stats(images: NDArray[np.uint8]) -> Stats:
    """Stats of (n, H, W, 3) uint8 images per channel, in [0, 1], shaped (3, 1, 1); the
    count is the number of images, as LeRobot counts it."""
    px = images.reshape(-1, images.shape[-1]).astype(np.float64) / 255.0
    s = vector_stats(px)
    s = {k: v.reshape(-1, 1, 1) for k, v in s.items() if k != "count"}
    s["count"] = np.array([images.shape[0]], dtype=np.float64)
    return s


def merge(stats: list[Stats]) -> Stats:
    """One feature's stats over several episodes."""
    counts = np.array([s["count"][0] for s in stats], dtype=np.float64)
    w = counts / counts.sum()

    def weighted(key: str) -> NDArray:
        return sum(wi * s[key] for wi, s in zip(w, stats))

    mean = weighted("mean")
    var = sum(wi * (s["std"] ** 2 + (s["mean"] - mean) ** 2) for wi, s in zip(w, stats))
    out = {
        "min": np.min([s["min"] for s in stats], axis=0),
        "max": np.max([s["max"] for s in stats], axis=0),
        "mean": mean,
        "std": np.sqrt(var),
        "count": np.array([counts.sum()]),
    }
    out.update({k: weighted(k) for k in QUANTILES if all(k in s for s in stats)})
    return out


def to_json(stats: dict[str, Stats]) -> dict:
    return {f: {k: np.asarray(v).tolist() for k, v in s.items()} for f, s in stats.items()}
