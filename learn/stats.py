"""Feature statistics as LeRobot keeps them (min, max, mean, std, count and the q01, q10,
q50, q90, q99 quantiles), per episode and merged over a dataset.

Vectors are reduced over frames (one value per element); images over frames and pixels,
per channel, scaled to [0, 1] and shaped (3, 1, 1) as LeRobot's image stats are. Pixels
are 8-bit, so an image feature's stats come from per-channel histograms of every frame
(`image_histogram`, summed): exact over all frames and pixels, quantiles included, at the
cost of one histogram per distinct picture.
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


def image_histogram(rgb: NDArray[np.uint8]) -> NDArray[np.int64]:
    """(3, 256) pixel counts per channel of one (H, W, 3) uint8 image."""
    flat = rgb.reshape(-1, rgb.shape[-1])
    return np.stack([np.bincount(flat[:, c], minlength=256) for c in range(flat.shape[1])])


def histogram_stats(hist: NDArray[np.int64], images: int) -> Stats:
    """Stats of every pixel counted in a (3, 256) histogram, per channel, in [0, 1] and
    shaped (3, 1, 1); the quantiles are `np.quantile`'s (linear) over those pixels. The
    count is the number of images, as LeRobot counts it."""
    h = np.asarray(hist, dtype=np.float64)
    v = np.arange(h.shape[1], dtype=np.float64) / 255.0
    n = h.sum(1)
    mean = h @ v / n
    var = (h * (v[None, :] - mean[:, None]) ** 2).sum(1) / n
    seen = h > 0
    out = {
        "min": v[seen.argmax(1)],
        "max": v[h.shape[1] - 1 - seen[:, ::-1].argmax(1)],
        "mean": mean,
        "std": np.sqrt(var),
    }
    cum = np.cumsum(hist, axis=1)
    for key, q in QUANTILES.items():
        pos = q * (n - 1)  # np.quantile's linear rule on the sorted pixels
        lo, hi = np.floor(pos), np.ceil(pos)
        at_lo = np.array([np.searchsorted(c, k, side="right") for c, k in zip(cum, lo)])
        at_hi = np.array([np.searchsorted(c, k, side="right") for c, k in zip(cum, hi)])
        out[key] = v[at_lo] + (v[at_hi] - v[at_lo]) * (pos - lo)
    out = {k: a.reshape(-1, 1, 1) for k, a in out.items()}
    out["count"] = np.array([images], dtype=np.float64)
    return out


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
