"""Training loop for the force estimator on in-memory arrays, with resumable state.

``fit`` is what both the train CLI and the data-scaling benchmark call. Resume state is a run state of
``controltac_il.run_state`` (model, AdamW moments, LR schedule, sampler RNG), never pickle.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as F

from controltac_il.checkpoint import read_json
from controltac_il.estimators.config import EstimatorConfig, EstimatorTrainConfig
from controltac_il.estimators.estimator import ForceEstimator, preprocess, validate_residuals
from controltac_il.io import atomic_dir
from controltac_il.run_state import load_run_state, save_run_state
from controltac_il.training import optimise

def force_stats(forces: np.ndarray) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Per-axis mean and std (std floored at 0.05 N) of training labels (N, 3)."""
    mean = forces.mean(axis=0)
    std = np.maximum(forces.std(axis=0), 0.05)
    return tuple(float(v) for v in mean), tuple(float(v) for v in std)


def mae_per_axis(est: ForceEstimator, residuals: np.ndarray, forces: np.ndarray) -> np.ndarray:
    """Mean absolute error per axis [Fx, Fy, Fz] in N."""
    return np.abs(est.predict(residuals) - forces).mean(axis=0)


def _loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The training loss: L1 on normalised forces."""
    return F.l1_loss(pred, target)


def _save_state(path: Path, est: ForceEstimator, opt: torch.optim.Optimizer, sched, gen: torch.Generator,
                step: int, train: EstimatorTrainConfig, history: list) -> None:
    meta = {"step": step, "train": asdict(train), "model": est.config.to_dict(), "history": history}
    with atomic_dir(path) as tmp:
        save_run_state(tmp / "state", {"model": est.model}, meta, opt, sched, tensors={"rng": gen.get_state()})


def _load_state(path: Path | None, est: ForceEstimator, opt: torch.optim.Optimizer, gen: torch.Generator) -> dict:
    """Restore the training state saved in ``path``; its metadata (step, history, lr_schedule)."""
    if path is None or not (path / "state.json").is_file():
        raise FileNotFoundError(f"--resume: no training state found in {path}")
    if read_json(path / "state.json")["model"] != est.config.to_dict():
        raise ValueError(f"resume state in {path} was made for another model config; start a fresh run or use the same config")
    meta, tensors = load_run_state(path / "state", {"model": est.model}, opt)
    gen.set_state(tensors["rng"])
    return meta


def _checked(residuals: np.ndarray, forces: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Validated residuals uint8 (N, H, W, 3) and forces float32 (N, 3) N; ValueError naming ``what``."""
    residuals = validate_residuals(residuals, "val residuals" if what.startswith("val") else "residuals")
    forces = np.asarray(forces, dtype=np.float32)
    if forces.ndim != 2 or forces.shape[1] != 3 or len(forces) != len(residuals):
        raise ValueError(f"{what} must have shape (N, 3) matching residuals (N={len(residuals)}), got {forces.shape}")
    if not np.isfinite(forces).all():
        raise ValueError(f"{what} contain NaN or infinite values")
    return residuals, forces


def _prepared(residuals: np.ndarray, forces: np.ndarray, model_config: EstimatorConfig | None
              ) -> tuple[EstimatorConfig, np.ndarray, np.ndarray]:
    """(the model config with ``force_mean`` / ``force_std`` set from ``forces``, validated residuals, forces)."""
    residuals, forces = _checked(residuals, forces, "forces")
    mean, std = force_stats(forces)
    cfg = EstimatorConfig(**{**(model_config or EstimatorConfig()).to_dict(), "force_mean": mean, "force_std": std})
    return cfg, residuals, forces


def _start(residuals, forces, model_config, init, seed: int):
    """(the estimator to train: fresh with ``model_config``, or ``init``'s config (its force normalisation: its
    weights were trained with it) and weights; checked residuals; forces)."""
    if init is not None and init.config.input_mix is not None:
        raise ValueError("init: a colour-calibrated estimator (input_mix set) is calibrated further by "
                         "estimators.few_shot, not fine-tuned by fit")
    cfg, residuals, forces = _prepared(residuals, forces, model_config if init is None else init.config)
    torch.manual_seed(seed)
    est = ForceEstimator(init.config if init is not None else cfg)
    if init is not None:
        est.model.load_state_dict(init.model.state_dict())
    return est, residuals, forces


def fit(
    residuals: np.ndarray,
    forces: np.ndarray,
    model_config: EstimatorConfig | None = None,
    train: EstimatorTrainConfig | None = None,
    val: tuple[np.ndarray, np.ndarray] | None = None,
    state_dir: str | Path | None = None,
    resume: bool = False,
    progress: bool = True,
    on_checkpoint: Callable[[ForceEstimator, int, list], None] | None = None,
    init: ForceEstimator | None = None,
) -> tuple[ForceEstimator, list[dict]]:
    """Train a force estimator on residuals uint8 (N, H, W, 3) and forces float (N, 3) in N.

    Images are resized once to the model input size. ``force_mean``/``force_std`` of the model
    config are set from ``forces``. With ``state_dir`` the resumable state is written there every
    ``train.checkpoint_every`` steps and at the end; ``resume=True`` continues from it; ``on_checkpoint(est, step,
    history)`` is called after each intermediate state write. ``init``: fine-tune that estimator (its config,
    force normalisation included, and weights) instead of a fresh one. A NaN / inf loss raises NonFiniteLoss before any
    update from it (the last saved state is the last good one); Ctrl-C saves the current step (and calls
    ``on_checkpoint``), then raises TrainingInterrupted. Returns the estimator (eval mode) and the evaluation
    history (step, val MAE per axis).
    """
    train = train or EstimatorTrainConfig()
    val = None if val is None else _checked(*val, "val forces")
    est, residuals, forces = _start(residuals, forces, model_config, init, train.seed)
    cfg = est.config
    x_all, y_all = _to_input(residuals, cfg), est.normalise_forces(torch.from_numpy(forces))
    opt = torch.optim.AdamW(est.model.parameters(), lr=train.lr, weight_decay=train.weight_decay)
    gen = torch.Generator().manual_seed(train.seed)
    state_path = Path(state_dir) if state_dir is not None else None
    meta = _load_state(state_path, est, opt, gen) if resume else {"step": 0, "history": []}
    step, history = int(meta["step"]), list(meta["history"])
    sched = train.schedule(opt, meta.get("lr_schedule") if resume else None, step)

    def batch_loss(step: int) -> torch.Tensor:
        idx = torch.randint(0, len(x_all), (min(train.batch_size, len(x_all)),), generator=gen)
        x = x_all[idx].float().sub_(cfg.residual_offset).div_(cfg.residual_scale)
        return _loss(est.model(x), y_all[idx])

    def after_step(at: int, out) -> None:
        if val is not None and ((train.eval_every and at % train.eval_every == 0) or at == train.steps):
            mae = mae_per_axis(est, *val)
            history.append({"step": at, "val_mae": [float(v) for v in mae], "val_mae_mean": float(mae.mean())})
            est.model.train()

    def save(at: int, loss: float) -> None:
        _save_state(state_path, est, opt, sched, gen, at, train, history)
        if on_checkpoint is not None and at < train.steps:
            on_checkpoint(est, at, history)

    est.model.train()
    optimise(step, train.steps, batch_loss, opt, sched, list(est.model.parameters()),
             save if state_path is not None else None, train.checkpoint_every, "train estimator", grad_clip=0.0,
             after_step=after_step, state=str(state_path), progress=progress)
    est.model.eval()
    return est, history


def _to_input(residuals: np.ndarray, cfg: EstimatorConfig, chunk: int = 512) -> torch.Tensor:
    """Resize residuals to the model input once; keep them as uint8 (N, 3, h, w) to save memory."""
    out = []
    for i in range(0, len(residuals), chunk):
        x = preprocess(residuals[i : i + chunk], cfg) * cfg.residual_scale + cfg.residual_offset
        out.append(x.round_().clamp_(0, 255).to(torch.uint8))
    return torch.cat(out)
