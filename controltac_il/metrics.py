"""Metrics as in the paper: MSE on 0–255 RGB, SSIM, force MAE; success rates with their Wilson interval."""

from __future__ import annotations

import numpy as np
from skimage.metrics import structural_similarity


def _pair(a, b, name_a="a", name_b="b"):
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        raise ValueError(f"{name_a} and {name_b} must have the same shape, got {a.shape} and {b.shape}")
    if a.ndim < 3 or a.shape[-1] != 3:
        raise ValueError(f"images must be (..., H, W, 3) RGB, got {a.shape}")
    return a, b


def mse(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean squared error on the 0–255 scale per image: (..., H, W, 3) → (...)."""
    a, b = _pair(a, b)
    d = a.astype(np.float64) - b.astype(np.float64)
    return (d * d).mean(axis=(-3, -2, -1))


def ssim(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """SSIM (scikit-image, 7×7 window, data range 255, channels averaged) per image: (..., H, W, 3) → (...)."""
    a, b = _pair(a, b)
    flat_a = a.reshape(-1, *a.shape[-3:])
    flat_b = b.reshape(-1, *b.shape[-3:])
    out = [
        structural_similarity(x, y, channel_axis=-1, data_range=255.0)
        for x, y in zip(flat_a.astype(np.float64), flat_b.astype(np.float64))
    ]
    return np.asarray(out, dtype=np.float64).reshape(a.shape[:-3])


def force_mae(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Mean absolute force error in N per sample over [Fx, Fy, Fz]: (..., 3) → (...)."""
    pred, true = np.asarray(pred, dtype=np.float64), np.asarray(true, dtype=np.float64)
    if pred.shape != true.shape or pred.shape[-1:] != (3,):
        raise ValueError(f"pred and true must both be (..., 3) forces, got {pred.shape} and {true.shape}")
    return np.abs(pred - true).mean(axis=-1)


def wilson_interval(successes: int, trials: int) -> tuple[float, float]:
    """Wilson score 95 % interval (low, high) of a success rate (scipy's); (0, 1) when there are no trials."""
    from scipy.stats import binomtest

    if trials < 0 or not 0 <= successes <= trials:
        raise ValueError(f"need 0 <= successes <= trials, got successes={successes}, trials={trials}")
    if trials == 0:
        return 0.0, 1.0
    ci = binomtest(int(successes), int(trials)).proportion_ci(confidence_level=0.95, method="wilson")
    return float(ci.low), float(ci.high)
