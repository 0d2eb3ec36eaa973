"""Few-shot Fz calibration of the force estimator to a sensor it never saw: a colour adapter before a frozen net.

Another sensor's optics (other LEDs, other light directions, another gain) mixes the residual's colour
channels differently; to first order that is a linear map of the colours. So the shipped network stays frozen
and only a 3x3 colour mix plus a shift (12 numbers, ``EstimatorConfig.input_mix`` / ``input_shift``) is fitted
on the sensor's Fz labels, pulled towards the identity. Chosen over the other candidates of
``benchmarks.calibration_methods`` (a frozen backbone with a ridge head, monotone maps of contact statistics and
of the shipped reading, a ridge on several statistics): at ~50 frames it reads 0.50x the constant against 0.65x
for the best of them (``benchmarks/results/calibration_methods.json``); ``benchmarks.calibration`` measures it end
to end. The mix applies to Fz alone: fitted without shear labels, it moved Fx / Fy from 0.25 / 0.29 to 0.46 / 1.42 N
MAE on a held-out sensor (``benchmarks.finetune``'s 100 presses, 72a4d0f), so Fx and Fy read the unmixed frame.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
import torch.nn.functional as F

from controltac_il.estimators.estimator import ForceEstimator, colour_mix, identity, preprocess, validate_residuals


@dataclasses.dataclass(frozen=True)
class ColourFit:
    """Settings of the colour adapter's fit: Adam ``steps`` at ``lr`` on the smooth-L1 Fz error (N), plus
    ``pull`` times the squared distance of the mix from the identity."""

    steps: int = 150
    lr: float = 5e-2
    pull: float = 1.0


def fit_colour_adapter(base: ForceEstimator, residuals: np.ndarray, fz: np.ndarray,
                       settings: ColourFit = ColourFit()) -> ForceEstimator:
    """A copy of ``base`` (weights frozen, shared values) whose colour mix is fitted on residuals uint8 (N, H, W, 3)
    labelled ``fz`` (N,) N; ValueError for a non-finite label or a NaN loss. Deterministic (full batch)."""
    fz = np.asarray(fz, dtype=np.float32)
    if fz.ndim != 1 or len(fz) != len(residuals) or not np.isfinite(fz).all():
        raise ValueError(f"fz: one finite label per residual, shape ({len(residuals)},), is needed; got {fz.shape}")
    x = preprocess(validate_residuals(residuals), base.config)
    start = base.config.input_mix if base.config.input_mix is not None else np.eye(3)
    mix = torch.tensor(np.asarray(start), dtype=torch.float32, requires_grad=True)
    shift = torch.tensor(base.config.input_shift, dtype=torch.float32, requires_grad=True)
    eye, target = torch.eye(3), torch.as_tensor(fz)
    opt = torch.optim.Adam([mix, shift], lr=settings.lr)
    model = base.model.eval().requires_grad_(False)
    try:
        for _ in range(settings.steps):
            loss = F.smooth_l1_loss(base.denormalise_forces(model(colour_mix(x, mix, shift)))[:, 2], target)
            loss = loss + settings.pull * ((mix - eye) ** 2).sum()
            if not torch.isfinite(loss):
                raise ValueError("the colour adapter's loss became NaN / inf: check the frames and labels")
            opt.zero_grad()
            loss.backward()
            opt.step()
    finally:
        model.requires_grad_(True)
    config = dataclasses.replace(base.config, input_mix=tuple(tuple(float(v) for v in row) for row in mix.detach().numpy()),
                                 input_shift=tuple(float(v) for v in shift.detach().numpy()))
    out = ForceEstimator(config, model=base.model, device=str(base.device))
    weights = base.checkpoint_hash if base.config.input_mix is None else None
    out.checkpoint_hash = identity(weights, config) if weights is not None else None
    return out


def held_out_mae(pred: np.ndarray, fz: np.ndarray, constant) -> dict:
    """Fz MAE (N) of predictions ``pred`` (N,) and of the constant baseline ``constant`` (a number or (N,)) against
    held-out labels ``fz`` (N,), their ratio (None where the constant's MAE is 0) and the correlation; the numbers
    ``calibrate`` reports."""
    pred, fz = np.asarray(pred, np.float64), np.asarray(fz, np.float64)
    if fz.ndim != 1 or not fz.size or pred.shape != fz.shape:
        raise ValueError(f"pred {pred.shape} and fz {fz.shape}: one Fz per held-out frame (N,) each, N >= 1")
    mae, base = float(np.abs(pred - fz).mean()), float(np.abs(constant - fz).mean())
    corr = float(np.corrcoef(pred, fz)[0, 1]) if np.std(pred) > 0 and np.std(fz) > 0 else None
    return {"mae_n": mae, "constant_mae_n": base, "ratio_to_constant": mae / base if base > 0 else None, "corr": corr,
            "frames": int(len(fz))}
