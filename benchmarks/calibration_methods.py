"""Calibrating the force estimator from tens of frames: which method beats the constant baseline.

    python -m benchmarks.calibration_methods --out calibration_methods.json [--quick]

A lab's sensor is played by a sensor the shipped estimator never saw: an instance of the held-out ``unseen`` family
(``controltac_il.tactile.instances``: DIGIT background, lighting gain 1.35-1.7, beyond the training band) rendered
with one of three optics: ``polynomial`` (the family's own), ``three_light``, and ``three_light_rot`` (the Mini
light vectors rotated 60 deg about the gel normal and the colour channels rolled: an optical design no training
instance has). Each frame is cropped to a square (another aspect ratio; the estimator stretches it to 64x80), and
the lighting drifts per grasp (gain +-2 %, offset +-2 grey levels) against one background per session.

A grasp is one object at one pose pressed along a loading ramp Fz 0 -> 10-14 N (smoothstep, 15-20 frames). Its
labels are Fz only, shifted by a lag of -1, 0 or +1 frame drawn per grasp (label[i] = Fz[i + lag]). A calibration
set is every ``--stride``-th labelled frame with label in [1, 10] N of K grasps (about 50 frames at K = 10); the
test set is the true Fz of all contact frames (Fz >= 0.5 N) of other grasps of the same sensor (other poses, the
held-out objects among them). Every hyperparameter is chosen by leave-one-grasp-out on the calibration grasps.
Methods: constant (the calibration labels' mean), zero_shot (the shipped estimator), stat_monotone (a monotone map
of a contact statistic), ship_monotone / ship_affine (the shipped Fz reading mapped by a monotone / affine 1-D
fit), stats_ridge (ridge on [shipped Fz, contact area, summed residual]), frozen_ridge (ridge on the shipped
network's 128-d penultimate features), colour_adapter (``estimators.few_shot``: a 3x3 mix and shift of the input's
colours before the frozen shipped network, fitted on the labels: what ``calibrate`` uses below 500 frames).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from benchmarks.common import base_parser, print_table, write_results
from controltac_il.generator.forces import VALIDATED_RANGE

SIZE = (120, 160)  # render size (H, W), the pad's aspect
CROP_W = 120  # kept columns: a square frame, another aspect ratio than the 64x80 input
LABEL_RANGE = VALIDATED_RANGE.fz  # N: the calibration labels kept, as calibrate keeps them
TEST_MIN_FZ = 0.5  # N: test frames with contact
ALPHAS = np.logspace(-2, 4, 13)  # ridge penalties tried by leave-one-grasp-out
OPTICS = ("polynomial", "three_light", "three_light_rot")
METHODS = ("constant", "zero_shot", "stat_monotone", "ship_monotone", "ship_affine", "stats_ridge", "frozen_ridge",
           "colour_adapter")

PROG = "python -m benchmarks.calibration_methods"


def ramp(n: int, fmax: float) -> np.ndarray:
    """Loading ramp Fz (n,) in N from 0 to ``fmax``: smoothstep, so mid-ramp frames move ~1.5x the mean step."""
    t = np.linspace(0.0, 1.0, n)
    return fmax * (3 * t**2 - 2 * t**3)


def lag_labels(fz: np.ndarray, lag: int) -> np.ndarray:
    """Labels (n,) of one grasp's frames when the force log lags by ``lag`` frames: label[i] = fz[i + lag],
    clamped to the ramp's ends."""
    idx = np.clip(np.arange(len(fz)) + int(lag), 0, len(fz) - 1)
    return np.asarray(fz)[idx]


def rotated_lights(angle_deg: float = 60.0) -> np.ndarray:
    """The Mini's light vectors (3, 3) rotated about z by ``angle_deg`` and with channels rolled by one."""
    from controltac_il.tactile.optics import MINI_LIGHTS

    a = np.deg2rad(angle_deg)
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]], dtype=np.float32)
    return np.roll(MINI_LIGHTS @ rot.T, 1, axis=0).astype(np.float32)


def make_sensor(index: int, optics: str, size=SIZE):
    """(name, TactileSensor) for unseen-family instance ``index`` with ``optics`` (one of OPTICS)."""
    from controltac_il.tactile.instances import sensor_instance
    from controltac_il.tactile.optics import ThreeLightOptics
    from controltac_il.tactile.sensor import TactileSensor

    inst = sensor_instance("unseen", index, size)
    sensor = TactileSensor(inst.spec, "polynomial" if optics == "polynomial" else "three_light", seed=index)
    if optics == "three_light_rot":
        sensor.optics = ThreeLightOptics(rotated_lights())
    return f"{inst.name}/{optics}", sensor


def render_grasp(sensor, obj: str, rng: np.random.Generator, crop_w: int = CROP_W):
    """Residuals uint8 (n, H, crop_w, 3) and true Fz (n,) N of one grasp: random pose, ramp and lighting drift."""
    from controltac_il.tactile.residual import to_residual

    half_h, half_w = (s / 2 for s in sensor.spec.pad_size_mm)
    pose = (rng.uniform(-0.4, 0.4) * half_w, rng.uniform(-0.6, 0.6) * half_h, rng.uniform(0, np.pi))
    targets = ramp(int(rng.integers(15, 21)), float(rng.uniform(10.0, 14.0)))
    gain, offset = rng.uniform(0.98, 1.02), rng.uniform(-2.0, 2.0, size=3)
    res, fz = [], []
    for f in targets:
        c = sensor.press(obj, pose, (0.0, 0.0, float(f)), noise_seed=int(rng.integers(2**31)))
        img = np.clip(np.rint(c.image.astype(np.float32) * gain + offset), 0, 255).astype(np.uint8)
        res.append(to_residual(img, sensor.background))
        fz.append(c.force[2])
    x0 = (res[0].shape[1] - crop_w) // 2
    return np.stack(res)[:, :, x0:x0 + crop_w], np.asarray(fz, dtype=np.float64)


def frame_features(est, residuals: np.ndarray) -> dict:
    """Per-frame features of residuals (N, H, W, 3): the shipped Fz (N,) N (gated), its penultimate activations
    (N, 128), contact area (share of pixels > AREA_GATE) and summed residual (``contact_signal``)."""
    import torch

    from controltac_il.calibrate.recordings import AREA_GATE, contact_signal
    from controltac_il.estimators.estimator import preprocess
    from controltac_il.tactile.residual import residual_magnitude

    fz = est.predict(residuals)[:, 2].astype(np.float64)
    hidden = []
    with torch.no_grad():
        for i in range(0, len(residuals), 128):
            f = est.model.features(preprocess(residuals[i:i + 128], est.config))
            pooled = torch.cat([f.mean(dim=(2, 3)), f.amax(dim=(2, 3))], dim=1)
            hidden.append(est.model.head[1](est.model.head[0](pooled)).numpy())
    mag = residual_magnitude(residuals)
    return {"fz_ship": fz, "hidden": np.concatenate(hidden).astype(np.float64),
            "area": (mag > AREA_GATE).mean(axis=(1, 2)).astype(np.float64), "summag": contact_signal(residuals)}


@dataclass
class Bank:
    """All rendered frames of one sensor: per-frame grasp id ``gid``, position ``pos`` in its grasp, true ``fz``
    (N), features (``frame_features`` of the shipped estimator ``base``) and the residuals ``res`` uint8 (N, H, W, 3);
    grasps ``cal_pool`` may calibrate, ``test`` are only scored."""

    name: str
    gid: np.ndarray
    pos: np.ndarray
    fz: np.ndarray
    feats: dict
    cal_pool: np.ndarray
    test: np.ndarray
    res: np.ndarray
    base: object


def make_bank(est, index: int, optics: str, n_cal: int, n_test: int, seed: int, size=SIZE, crop_w: int = CROP_W) -> Bank:
    """Render ``n_cal + n_test`` grasps of one sensor at ``size`` (H, W), frames cropped to ``crop_w`` columns
    (objects: the training and held-out ones, at random)."""
    from controltac_il.tactile import HELDOUT_OBJECTS, TRAIN_OBJECTS

    name, sensor = make_sensor(index, optics, size)
    objects = TRAIN_OBJECTS + HELDOUT_OBJECTS
    rng = np.random.default_rng([seed, index, OPTICS.index(optics)])
    gid, pos, fz, res = [], [], [], []
    for g in range(n_cal + n_test):
        r, f = render_grasp(sensor, objects[int(rng.integers(len(objects)))], rng, crop_w)
        gid += [g] * len(f)
        pos += list(range(len(f)))
        fz.append(f)
        res.append(r)
    res = np.concatenate(res)
    return Bank(name, np.asarray(gid), np.asarray(pos), np.concatenate(fz), frame_features(est, res),
                np.arange(n_cal), np.arange(n_cal, n_cal + n_test), res, est)


def calibration_set(bank: Bank, grasps, lags, stride: int, phase: int) -> tuple[np.ndarray, np.ndarray]:
    """(frame indices (M,), lagged labels (M,) N) of the calibration grasps: labels in LABEL_RANGE, every
    ``stride``-th frame from ``phase``."""
    rows, labels = [], []
    for g, lag in zip(grasps, lags):
        idx = np.flatnonzero(bank.gid == g)
        lab = lag_labels(bank.fz[idx], lag)
        keep = (lab >= LABEL_RANGE[0]) & (lab <= LABEL_RANGE[1]) & ((bank.pos[idx] - phase) % stride == 0)
        rows.append(idx[keep])
        labels.append(lab[keep])
    return np.concatenate(rows), np.concatenate(labels)


def scored_rows(bank: Bank) -> np.ndarray:
    """Frame indices of the test grasps with contact (true Fz >= TEST_MIN_FZ)."""
    return np.flatnonzero(np.isin(bank.gid, bank.test) & (bank.fz >= TEST_MIN_FZ))


class MonotoneMap:
    """Non-decreasing 1-D map y = m(x): isotonic regression on the fit points, linear between them, and beyond
    them the least-squares slope (>= 0) of all points."""

    def fit(self, x: np.ndarray, y: np.ndarray) -> "MonotoneMap":
        from scipy.optimize import isotonic_regression

        order = np.argsort(x, kind="stable")
        xs, ys = np.asarray(x, float)[order], isotonic_regression(np.asarray(y, float)[order]).x
        self.x, inv = np.unique(xs, return_inverse=True)
        self.y = np.bincount(inv, weights=ys) / np.bincount(inv)
        self.slope = max(float(np.polyfit(xs, ys, 1)[0]), 0.0) if len(self.x) > 1 else 0.0
        return self

    def predict(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, float)
        out = np.interp(x, self.x, self.y)
        out = np.where(x < self.x[0], self.y[0] + self.slope * (x - self.x[0]), out)
        return np.where(x > self.x[-1], self.y[-1] + self.slope * (x - self.x[-1]), out)


def ridge_path(x: np.ndarray, y: np.ndarray, alphas) -> list:
    """Ridge on standardised features x (M, D) -> y (M,), one SVD for all penalties; predict(x) -> (N,) each."""
    mu, sd = x.mean(0), x.std(0) + 1e-8
    ym = y.mean()
    u, s, vt = np.linalg.svd((x - mu) / sd, full_matrices=False)
    uy = u.T @ (y - ym)
    out = []
    for al in alphas:
        w = vt.T @ (s / (s**2 + al) * uy)
        out.append(lambda q, w=w: ((q - mu) / sd) @ w + ym)
    return out


def logo_mae(fit, x: np.ndarray, y: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Leave-one-grasp-out MAE (N) over the calibration grasps ``groups`` (M,) of ``fit(x, y)``, which returns one
    predictor or a list of them (then one MAE each)."""
    errs = []
    for g in np.unique(groups):
        out = groups == g
        fits = fit(x[~out], y[~out])
        errs.append([np.abs(f(x[out]) - y[out]) for f in (fits if isinstance(fits, list) else [fits])])
    return np.array([np.concatenate(e).mean() for e in zip(*errs)])


def fit_ridge(x, y, groups):
    """Ridge with the penalty chosen from ALPHAS by leave-one-grasp-out; returns (predict, alpha)."""
    alpha = float(ALPHAS[int(np.argmin(logo_mae(lambda a, b: ridge_path(a, b, ALPHAS), x, y, groups)))])
    return ridge_path(x, y, [alpha])[0], alpha


def monotone(x, y):
    m = MonotoneMap().fit(x, y)
    return m.predict


def affine(x, y):
    a, b = np.polyfit(x, y, 1) if np.ptp(x) > 0 else (0.0, float(np.mean(y)))
    return lambda q: a * q + b


def fit_method(method: str, bank: Bank, rows: np.ndarray, y: np.ndarray, adapter_steps: int = 150):
    """Fit ``method`` on calibration frames ``rows`` with labels ``y``; returns (predict(frame rows) -> Fz, info).
    adapter_steps: the colour adapter's full-batch steps (``calibrate``'s 150; fewer in a --quick run)."""
    f, groups = bank.feats, bank.gid[rows]
    if method == "constant":
        c = float(y.mean())
        return (lambda r: np.full(len(r), c)), {}
    if method == "zero_shot":
        return (lambda r: f["fz_ship"][r]), {}
    if method == "stat_monotone":  # the statistic with the lower leave-one-grasp-out error
        scores = {k: float(logo_mae(monotone, f[k][rows], y, groups)[0]) for k in ("area", "summag")}
        stat = min(scores, key=scores.get)
        m = monotone(f[stat][rows], y)
        return (lambda r: m(f[stat][r])), {"statistic": stat}
    if method in ("ship_monotone", "ship_affine"):
        m = (monotone if method == "ship_monotone" else affine)(f["fz_ship"][rows], y)
        return (lambda r: m(f["fz_ship"][r])), {}
    if method == "stats_ridge":
        stack = lambda r: np.stack([f["fz_ship"][r], f["area"][r], f["summag"][r]], 1)  # noqa: E731
        m, alpha = fit_ridge(stack(rows), y, groups)
        return (lambda r: m(stack(r))), {"alpha": alpha}
    if method == "frozen_ridge":
        m, alpha = fit_ridge(f["hidden"][rows], y, groups)
        return (lambda r: m(f["hidden"][r])), {"alpha": alpha}
    if method == "colour_adapter":
        from controltac_il.estimators.few_shot import ColourFit, fit_colour_adapter

        adapted = fit_colour_adapter(bank.base, bank.res[rows], y, ColourFit(steps=adapter_steps))
        return (lambda r: adapted.predict(bank.res[r])[:, 2].astype(np.float64)), {}
    raise ValueError(f"unknown method {method!r}; expected one of {METHODS}")


def score(pred: np.ndarray, true: np.ndarray) -> dict:
    """MAE (N) over all test frames and over those with true Fz in LABEL_RANGE, Pearson correlation (None for a
    constant prediction)."""
    corr = float(np.corrcoef(pred, true)[0, 1]) if np.std(pred) > 1e-9 else None
    inside = (true >= LABEL_RANGE[0]) & (true <= LABEL_RANGE[1])
    return {"mae": float(np.abs(pred - true).mean()), "mae_in_range": float(np.abs(pred - true)[inside].mean()),
            "corr": corr}


def run_draw(bank: Bank, k: int, rng: np.random.Generator, stride: int, methods=METHODS,
             adapter_steps: int = 150) -> list[dict]:
    """One calibration draw of ``k`` grasps: every method's test MAE, correlation and fit wall time."""
    grasps = rng.choice(bank.cal_pool, size=k, replace=False)
    lags = rng.integers(-1, 2, size=k)
    rows, y = calibration_set(bank, grasps, lags, stride, int(rng.integers(stride)))
    test = scored_rows(bank)
    out = []
    for m in methods:
        t0 = time.perf_counter()
        predict, info = fit_method(m, bank, rows, y, adapter_steps)
        fit_s = time.perf_counter() - t0
        out.append({"sensor": bank.name, "k": k, "method": m, "cal_frames": len(rows), "test_frames": len(test),
                    **score(predict(test), bank.fz[test]), "fit_s": fit_s, **info})
    return out


def summarise(records: list[dict]) -> list[dict]:
    """Per (K, method): MAE mean/SD over sensors x draws, mean ratio to the same draw's constant MAE, mean corr."""
    base = {(r["sensor"], r["k"], r["draw"]): r["mae"] for r in records if r["method"] == "constant"}
    base_in = {(r["sensor"], r["k"], r["draw"]): r["mae_in_range"] for r in records if r["method"] == "constant"}
    rows = []
    for k in sorted({r["k"] for r in records}):
        for m in METHODS:
            rs = [r for r in records if r["k"] == k and r["method"] == m]
            if not rs:
                continue
            mae = np.array([r["mae"] for r in rs])
            ratio = np.array([r["mae"] / base[(r["sensor"], r["k"], r["draw"])] for r in rs])
            inr = np.array([r["mae_in_range"] / base_in[(r["sensor"], r["k"], r["draw"])] for r in rs])
            corr = [r["corr"] for r in rs if r["corr"] is not None]
            rows.append({"k": k, "method": m, "cal_frames": float(np.mean([r["cal_frames"] for r in rs])),
                         "mae": float(mae.mean()), "mae_sd": float(mae.std()), "ratio": float(ratio.mean()),
                         "ratio_sd": float(ratio.std()), "ratio_worst": float(ratio.max()), "ratio_in_range": float(inr.mean()),
                         "corr": float(np.mean(corr)) if corr else None,
                         "fit_ms": 1e3 * float(np.median([r["fit_s"] for r in rs])), "n": len(rs)})
    return rows


def per_sensor(records: list[dict], k: int) -> list[dict]:
    """Mean MAE ratio to the constant per sensor and method at one K."""
    base = {(r["sensor"], r["draw"]): r["mae"] for r in records if r["method"] == "constant" and r["k"] == k}
    out = []
    for s in sorted({r["sensor"] for r in records}):
        row = {"sensor": s}
        for m in METHODS[1:]:
            v = [r["mae"] / base[(s, r["draw"])] for r in records if r["sensor"] == s and r["k"] == k and r["method"] == m]
            row[m] = float(np.mean(v)) if v else None
        out.append(row)
    return out


def settings(args) -> dict:
    """Sizes of the run: full or --quick."""
    if args.quick:
        return {"instances": [0], "optics": ["polynomial"], "n_cal": 6, "n_test": 2, "ks": [3, 5], "draws": 2,
                "size": (60, 80), "crop_w": 60, "adapter_steps": 3}
    return {"instances": [0, 1, 2], "optics": list(OPTICS), "n_cal": 20, "n_test": 12, "ks": [5, 10, 15],
            "draws": args.draws, "size": SIZE, "crop_w": CROP_W, "adapter_steps": 150}


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.split("\n\n")[0].split(": ", 1)[1])
    p.add_argument("--draws", type=int, default=8, help="calibration draws per sensor and K (default 8)")
    p.add_argument("--stride", type=int, default=2, help="keep every n-th labelled frame (default 2: ~5 a grasp)")
    p.add_argument("--seed", type=int, default=40)
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    args = p.parse_args(argv)
    import torch

    from controltac_il.estimators import ForceEstimator

    torch.set_num_threads(args.threads)
    cfg, est, t0 = settings(args), ForceEstimator.from_pretrained(None), time.perf_counter()
    records, banks = [], []
    for optics in cfg["optics"]:
        for index in cfg["instances"]:
            banks.append(make_bank(est, index, optics, cfg["n_cal"], cfg["n_test"], args.seed, cfg["size"],
                                   cfg["crop_w"]))
    render_s = time.perf_counter() - t0
    for si, bank in enumerate(banks):
        for k in cfg["ks"]:
            for d in range(cfg["draws"]):
                rng = np.random.default_rng([args.seed, si, k, d])
                records += [{**r, "draw": d} for r in run_draw(bank, k, rng, args.stride,
                                                               adapter_steps=cfg["adapter_steps"])]
    table = summarise(records)
    print_table(table, ["k", "method", "cal_frames", "mae", "mae_sd", "ratio", "ratio_sd", "ratio_worst", "ratio_in_range", "corr",
                        "fit_ms", "n"], title="Fz MAE (N) on test grasps; ratio = MAE / constant baseline's MAE")
    mid = cfg["ks"][len(cfg["ks"]) // 2]
    sensors = per_sensor(records, mid)
    print_table(sensors, ["sensor", *METHODS[1:]], title=f"ratio to the constant per sensor, K = {mid}")
    results = {"benchmark": "calibration_methods", "settings": {**cfg, "stride": args.stride, "seed": args.seed,
               "label_range_n": LABEL_RANGE, "test_min_fz_n": TEST_MIN_FZ},
               "summary": table, "per_sensor": sensors, "records": records,
               "render_s": round(render_s, 1), "wall_s": round(time.perf_counter() - t0, 1)}
    print(f"\nrendered {len(banks)} sensors in {render_s:.0f} s; total {results['wall_s']:.0f} s")
    return write_results(args.out, results)


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
