"""Computes a LeRobot v3.0 folder's stats: per episode and across episodes, of vectors and of cameras.

Stats follow LeRobot 0.4.4 (``compute_stats.py``): per episode min, max, mean, std, count and the quantiles
``QUANTILES`` of every feature; cameras per channel as (3, 1, 1) lists in [0, 1] over the frames
``sample_indices`` picks (strided when the long side is >= 300 px), count = frames sampled; across episodes
count-weighted means, pooled variance, min of mins, max of maxes, quantiles as the count-weighted mean of the
episodes'. Two departures, both in LeRobot's favour: camera std in float (0.4.4 squares uint8 and overflows,
huggingface/lerobot#3682) and exact per-episode quantiles (LeRobot bins a 5000-bin histogram).
"""

from __future__ import annotations

import numpy as np

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
STAT_NAMES = ("min", "max", "mean", "std", "count", *(f"q{round(q * 100):02d}" for q in QUANTILES))


def sample_indices(length: int) -> np.ndarray:
    """Frames of an episode of ``length`` whose images enter its stats (LeRobot's rule)."""
    n = length if length < 100 else max(100, min(int(length ** 0.75), 10000))
    return np.round(np.linspace(0, length - 1, n)).astype(int)


def image_stats(frames: np.ndarray) -> dict:
    """Stats of RGB uint8 (n, H, W, 3) sampled frames: per channel, (3, 1, 1) lists in [0, 1]."""
    return histogram_stats(frame_histograms(frames).sum(0), len(frames))


def frame_histograms(frames: np.ndarray) -> np.ndarray:
    """int64 (n, 3, 256): each channel's histogram of each of RGB uint8 (n, H, W, 3) frames, over the pixels
    their stats read (strided when the long side is >= 300 px). Summed over frames they give ``image_stats``
    exactly, so the histogram of a frame several episodes hold (a copy's unchanged frames) is computed once."""
    long_side = max(frames.shape[1:3])
    stride = int(long_side / 150) if long_side >= 300 else 1
    out = np.zeros((len(frames), 3, 256), np.int64)
    for i, frame in enumerate(frames[:, ::stride, ::stride]):
        for c in range(3):
            out[i, c] = np.bincount(frame[..., c].ravel(), minlength=256)
    return out


def histogram_stats(counts: np.ndarray, frames: int) -> dict:
    """Stats of ``frames`` sampled frames from their summed channel histograms int (3, 256) (``image_stats``)."""
    stats = [channel_stats(counts[c]) for c in range(3)]
    out = {k: [[[st[k] / 255.0]] for st in stats] for k in STAT_NAMES if k != "count"}
    return {**out, "count": [int(frames)]}


def channel_stats(counts: np.ndarray) -> dict:
    """min, max, mean, std and quantiles (as ``np.quantile``'s linear rule) of uint8 values given by their
    256-bin histogram (256,): exact, and without sorting."""
    counts = counts.astype(np.float64)
    levels = np.arange(256, dtype=np.float64)
    n = counts.sum()
    mean = float((counts * levels).sum() / n)
    out = {"min": float(np.flatnonzero(counts)[0]), "max": float(np.flatnonzero(counts)[-1]), "mean": mean,
           "std": float(np.sqrt((counts * (levels - mean) ** 2).sum() / n))}
    upto = np.cumsum(counts)  # upto[v]: values <= v
    for q in QUANTILES:
        pos = q * (n - 1)
        lo, hi = (int(np.searchsorted(upto, k, side="right")) for k in (np.floor(pos), np.ceil(pos)))
        out[f"q{round(q * 100):02d}"] = lo + (hi - lo) * (pos - np.floor(pos))
    return out


def vector_stats(values: np.ndarray, name: str) -> dict:
    """Stats of a numeric column (N,) or (N, D): lists of D (of 1 for scalars); integers' min / max stay ints."""
    values = np.asarray(values)
    if values.dtype.kind == "f" and not np.isfinite(values).all():
        raise ValueError(f"dataset: feature {name!r} holds NaN or inf; refusing to write stats of it")
    as_2d = values.reshape(len(values), -1)
    stats = _stats(as_2d.astype(np.float64))
    out = {k: np.asarray(stats[k]).tolist() for k in STAT_NAMES if k != "count"}
    if values.dtype.kind in "iub":
        out["min"], out["max"] = as_2d.min(0).astype(int).tolist(), as_2d.max(0).astype(int).tolist()
    return {**out, "count": [len(values)]}


def _stats(x: np.ndarray) -> dict:
    """min, max, mean, std and quantiles over the rows of (N, D) float64."""
    out = {"min": x.min(0), "max": x.max(0), "mean": x.mean(0), "std": x.std(0)}
    for q, v in zip(QUANTILES, np.quantile(x, QUANTILES, axis=0)):
        out[f"q{round(q * 100):02d}"] = v
    return out


def complete_stats(stats: dict | None, feature: dict) -> bool:
    """Whether ``stats`` (one episode's of ``feature``, as meta/episodes holds them) has every stat of
    STAT_NAMES, finite, of the feature's shape ((3, 1, 1) a camera's, else the feature's size), count > 0,
    min <= mean <= max, and a camera's in [0, 1] (as LeRobot's and ours)."""
    if not stats or any(k not in stats for k in STAT_NAMES):
        return False
    camera = feature["dtype"] in ("image", "video")
    shape = (3, 1, 1) if camera else (int(np.prod(feature["shape"])),)
    try:
        values = {k: np.asarray(stats[k], np.float64) for k in STAT_NAMES if k != "count"}
        count = np.asarray(stats["count"], np.float64)
    except (TypeError, ValueError):
        return False
    if count.shape != (1,) or not count[0] > 0 or any(v.shape != shape or not np.isfinite(v).all()
                                                      for v in values.values()):
        return False
    lo, mean, hi = values["min"], values["mean"], values["max"]
    return bool(np.all(lo <= mean) and np.all(mean <= hi) and (not camera or (np.all(lo >= 0) and np.all(hi <= 1))))


def aggregate_stats(episodes: list[dict]) -> dict:
    """Dataset stats {feature: {stat: list}} from per-episode stats (module docstring)."""
    out = {}
    for key in episodes[0]:
        per = [ep[key] for ep in episodes]
        count = np.array([p["count"][0] for p in per], np.float64)
        w = (count / count.sum()).reshape(-1, *([1] * np.asarray(per[0]["mean"]).ndim))
        mean = np.stack([np.asarray(p["mean"], np.float64) for p in per])
        std = np.stack([np.asarray(p["std"], np.float64) for p in per])
        total_mean = (w * mean).sum(0)
        variance = (w * (std ** 2 + (mean - total_mean) ** 2)).sum(0)
        agg = {"min": np.min([p["min"] for p in per], 0), "max": np.max([p["max"] for p in per], 0),
               "mean": total_mean, "std": np.sqrt(variance), "count": [int(count.sum())]}
        for q in STAT_NAMES[5:]:
            agg[q] = (w * np.stack([np.asarray(p[q], np.float64) for p in per])).sum(0)
        out[key] = {k: (v if isinstance(v, list) else v.tolist()) for k, v in agg.items()}
    return out
