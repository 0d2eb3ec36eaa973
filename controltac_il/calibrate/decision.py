"""Whether a calibrated estimator may read a sensor's unlabelled frames: held out grasp by grasp, with a margin.

ForceAugment uses an estimated reference force only to keep targets inside the validated range; an estimate that
is worse than a constant does harm there. So the estimator is used only when, over its held-out grasps, the upper
end of a bootstrap interval of its Fz MAE ÷ the constant's is below 1 **and** it beats the constant on most of
those grasps. A grasp is the unit: frames of one grasp share their object, pose and lighting, so resampling
frames would hide what a new object does (several-fold differences of scale between objects are the failure this
guards against).
"""

from __future__ import annotations

import numpy as np

MIN_GRASPS = 3  # below this no grasp-level interval exists: refused
BOOTSTRAP = 2000  # resamples of the grasps
LEVEL = 0.95
NO_ERROR = 1e-12  # N: a resample's constant error sum below this has no ratio; its quotient exceeds UNBOUNDED
UNBOUNDED = 1e6  # a ratio end above this comes only from such resamples


def per_grasp(pred: np.ndarray, fz: np.ndarray, constant: np.ndarray, grasps: np.ndarray) -> list[dict]:
    """One row per grasp with held-out frames (``pred`` finite): frames, Fz MAE of the estimator and of the constant
    (N), their ratio (None where the constant's MAE is 0: no ratio exists). pred, fz, constant, grasps: (N,);
    ``constant`` is the prediction without the estimator."""
    rows = []
    held = np.isfinite(pred)
    for g in np.unique(grasps[held]):
        m = held & (grasps == g)
        est, const = float(np.abs(pred[m] - fz[m]).mean()), float(np.abs(constant[m] - fz[m]).mean())
        rows.append({"grasp": int(g), "frames": int(m.sum()), "mae_n": est, "constant_mae_n": const,
                     "ratio": est / const if const > 0 else None})
    return rows


def ratio_interval(rows: list[dict], level: float = LEVEL) -> tuple[float, float | None]:
    """``level`` percentile bootstrap interval, over grasps resampled with replacement, of the frame-weighted MAE ratio
    sum(estimator's absolute errors) ÷ sum(the constant's); upper end None where the resamples that reach it draw
    only grasps whose constant has no error (no ratio exists: the interval has no upper end)."""
    from scipy import stats

    est = np.array([r["mae_n"] * r["frames"] for r in rows])
    const = np.array([r["constant_mae_n"] * r["frames"] for r in rows])

    def ratio(e, c, axis=-1):
        return e.sum(axis) / np.maximum(c.sum(axis), NO_ERROR)

    res = stats.bootstrap((est, const), ratio, paired=True, vectorized=True, n_resamples=BOOTSTRAP,
                          confidence_level=level, method="percentile", random_state=0)
    high = float(res.confidence_interval.high)
    return float(res.confidence_interval.low), high if high < UNBOUNDED else None


def decide(rows: list[dict], level: float = LEVEL) -> dict:
    """The decision over held-out grasp rows (``per_grasp``): used, the ratio, its ``level`` interval, the grasps
    won and the one line that says why."""
    if len(rows) < MIN_GRASPS:
        return {"use": False, "ratio_to_constant": None, "interval": None, "wins": None, "grasps": len(rows),
                "why": f"estimator declined: {len(rows)} held-out grasps, fewer than the {MIN_GRASPS} an interval "
                       "over grasps needs; ForceAugment takes the nominal reference force for unlabelled frames"}
    frames = sum(r["frames"] for r in rows)
    est_sum, const_sum = (sum(r[k] * r["frames"] for r in rows) for k in ("mae_n", "constant_mae_n"))
    if const_sum == 0:
        return {"use": False, "ratio_to_constant": None, "interval": None, "wins": 0, "grasps": len(rows),
                "why": "estimator declined: the constant's held-out Fz MAE is 0 N (every held-out label equals it), "
                       "nothing to improve on; ForceAugment takes the nominal reference force for unlabelled frames"}
    ratio, mae, const = est_sum / const_sum, est_sum / frames, const_sum / frames
    low, high = ratio_interval(rows, level)
    wins = sum(r["mae_n"] < r["constant_mae_n"] for r in rows)
    use = high is not None and bool(high < 1.0) and wins > len(rows) / 2  # a NaN end is no evidence: declined
    ends = f"from {low:.2f} with no upper end" if high is None else f"{low:.2f}-{high:.2f}"
    figures = (f"held-out Fz MAE {mae:.2f} N against the constant's {const:.2f} N ({ratio:.2f}x, "
               f"{level:.0%} interval {ends} over {len(rows)} grasps; better on {wins} of {len(rows)})")
    if use:
        why = f"estimator used for unlabelled frames: {figures}"
    else:
        reach = "the interval has no upper end" if high is None else "the interval reaches 1"
        missing = " and ".join(m for m, failed in ((reach, high is None or bool(high >= 1.0)),
                                                   ("it loses on most grasps", wins <= len(rows) / 2)) if failed)
        missing = missing or "no finite interval"
        why = (f"estimator declined ({missing}): {figures}; ForceAugment takes the nominal reference force for "
               "unlabelled frames")
    return {"use": bool(use), "ratio_to_constant": ratio, "interval": [low, high], "wins": int(wins),
            "grasps": len(rows), "why": why}
