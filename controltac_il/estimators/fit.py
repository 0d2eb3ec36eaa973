"""Training loop for the force estimator on in-memory arrays, with resumable state.

``fit`` is what both the train CLI and the data-scaling benchmark call. Resume state is written as
safetensors (model, AdamW moments, sampler RNG) + JSON (step, hyper-parameters), never pickle.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as F
from safetensors.torch import load_file, save_file
from tqdm.auto import tqdm

from controltac_il.estimators.config import EstimatorConfig
from controltac_il.estimators.estimator import ForceEstimator, preprocess, validate_residuals
from controltac_il.io import atomic_dir, write_json

STATE_DIR = "train_state"


@dataclass
class TrainConfig:
    """Optimisation settings.

    Fields:
        steps: number of AdamW updates (fixed budget, independent of the data size).
        batch_size: images per update.
        lr, min_lr: peak and final learning rate of the cosine schedule (after ``warmup`` steps).
        warmup: linear warm-up steps.
        weight_decay: AdamW weight decay.
        seed: seeds the weights and the batch sampler.
        checkpoint_every: write resumable state every this many steps (0 = only at the end).
        eval_every: evaluate on the validation arrays every this many steps (0 = only at the end).
    """

    steps: int = 3000
    batch_size: int = 64
    lr: float = 2e-3
    min_lr: float = 2e-5
    warmup: int = 100
    weight_decay: float = 1e-4
    seed: int = 0
    checkpoint_every: int = 250
    eval_every: int = 500

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"TrainConfig.{name} must be a positive int, got {getattr(self, name)!r}")
        for name in ("warmup", "checkpoint_every", "eval_every"):
            if int(getattr(self, name)) < 0:
                raise ValueError(f"TrainConfig.{name} must be >= 0, got {getattr(self, name)!r}")
        if not (self.lr > 0 and 0 <= self.min_lr <= self.lr):
            raise ValueError(f"TrainConfig needs lr > 0 and 0 <= min_lr <= lr, got lr={self.lr}, min_lr={self.min_lr}")
        if self.weight_decay < 0:
            raise ValueError(f"TrainConfig.weight_decay must be >= 0, got {self.weight_decay}")

    def lr_at(self, step: int) -> float:
        """Learning rate for update ``step`` (0-based): linear warm-up, then cosine to ``min_lr``."""
        if step < self.warmup:
            return self.lr * (step + 1) / self.warmup
        t = (step - self.warmup) / max(1, self.steps - self.warmup)
        return self.min_lr + 0.5 * (self.lr - self.min_lr) * (1 + math.cos(math.pi * min(t, 1.0)))


def force_stats(forces: np.ndarray) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Per-axis mean and std (std floored at 0.05 N) of training labels (N, 3)."""
    mean = forces.mean(axis=0)
    std = np.maximum(forces.std(axis=0), 0.05)
    return tuple(float(v) for v in mean), tuple(float(v) for v in std)


def mae_per_axis(est: ForceEstimator, residuals: np.ndarray, forces: np.ndarray) -> np.ndarray:
    """Mean absolute error per axis [Fx, Fy, Fz] in N."""
    return np.abs(est.predict(residuals) - forces).mean(axis=0)


def _save_state(path: Path, est: ForceEstimator, opt: torch.optim.Optimizer, gen: torch.Generator,
                step: int, train: TrainConfig, history: list) -> None:
    tensors = {f"model.{k}": v.detach().cpu().contiguous() for k, v in est.model.state_dict().items()}
    sd = opt.state_dict()
    for idx, st in sd["state"].items():
        for k, v in st.items():
            tensors[f"opt.{idx}.{k}"] = torch.as_tensor(v).detach().cpu().contiguous()
    tensors["rng"] = gen.get_state()
    meta = {"step": step, "train": asdict(train), "model": est.config.to_dict(),
            "param_groups": sd["param_groups"], "history": history}
    with atomic_dir(path) as tmp:
        save_file(tensors, str(tmp / "state.safetensors"))
        write_json(tmp / "state.json", meta)


def _load_state(path: Path, est: ForceEstimator, opt: torch.optim.Optimizer, gen: torch.Generator) -> tuple[int, list]:
    meta = json.loads((path / "state.json").read_text())
    tensors = load_file(str(path / "state.safetensors"))
    if meta["model"] != est.config.to_dict():
        raise ValueError(f"resume state in {path} was made for another model config; start a fresh run or use the same config")
    est.model.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model.")})
    state: dict[int, dict] = {}
    for k, v in tensors.items():
        if k.startswith("opt."):
            _, idx, name = k.split(".", 2)
            state.setdefault(int(idx), {})[name] = v
    opt.load_state_dict({"state": state, "param_groups": meta["param_groups"]})
    gen.set_state(tensors["rng"])
    return int(meta["step"]), list(meta["history"])


def fit(
    residuals: np.ndarray,
    forces: np.ndarray,
    model_config: EstimatorConfig | None = None,
    train: TrainConfig | None = None,
    val: tuple[np.ndarray, np.ndarray] | None = None,
    state_dir: str | Path | None = None,
    resume: bool = False,
    progress: bool = True,
    on_checkpoint: Callable[[ForceEstimator, int, list], None] | None = None,
) -> tuple[ForceEstimator, list[dict]]:
    """Train a force estimator on residuals uint8 (N, H, W, 3) and forces float (N, 3) in N.

    Images are resized once to the model input size. ``force_mean``/``force_std`` of the model
    config are set from ``forces``. With ``state_dir`` the resumable state is written there every
    ``train.checkpoint_every`` steps; ``resume=True`` continues from it; ``on_checkpoint(est, step, history)`` is called after each
    intermediate state write. Returns the estimator
    (eval mode) and the evaluation history (step, val MAE per axis).
    """
    train = train or TrainConfig()
    residuals = validate_residuals(residuals)
    forces = np.asarray(forces, dtype=np.float32)
    if forces.ndim != 2 or forces.shape[1] != 3 or len(forces) != len(residuals):
        raise ValueError(f"forces must have shape (N, 3) matching residuals (N={len(residuals)}), got {forces.shape}")
    if not np.isfinite(forces).all():
        raise ValueError("forces contain NaN or infinite values")
    mean, std = force_stats(forces)
    cfg = EstimatorConfig(**{**(model_config or EstimatorConfig()).to_dict(), "force_mean": mean, "force_std": std})

    torch.manual_seed(train.seed)
    est = ForceEstimator(cfg)
    x_all = _to_input(residuals, cfg)
    y_all = est.normalise_forces(torch.from_numpy(forces))
    opt = torch.optim.AdamW(est.model.parameters(), lr=train.lr, weight_decay=train.weight_decay)
    gen = torch.Generator().manual_seed(train.seed)
    step, history = 0, []
    state_path = Path(state_dir) if state_dir is not None else None
    if resume:
        if state_path is None or not (state_path / "state.json").is_file():
            raise FileNotFoundError(f"--resume: no training state found in {state_path}")
        step, history = _load_state(state_path, est, opt, gen)

    def evaluate(at: int) -> None:
        if val is not None:
            mae = mae_per_axis(est, *val)
            history.append({"step": at, "val_mae": [float(v) for v in mae], "val_mae_mean": float(mae.mean())})
            est.model.train()

    est.model.train()
    bar = tqdm(total=train.steps, initial=step, desc="train estimator", disable=not progress, dynamic_ncols=True)
    n = len(x_all)
    while step < train.steps:
        idx = torch.randint(0, n, (min(train.batch_size, n),), generator=gen)
        x = x_all[idx].float().sub_(cfg.residual_offset).div_(cfg.residual_scale)
        loss = F.l1_loss(est.model(x), y_all[idx])
        for g in opt.param_groups:
            g["lr"] = train.lr_at(step)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        bar.update(1)
        bar.set_postfix(loss=f"{loss.item():.4f}")
        if train.eval_every and step % train.eval_every == 0 and step < train.steps:
            evaluate(step)
        if state_path is not None and train.checkpoint_every and step % train.checkpoint_every == 0 and step < train.steps:
            _save_state(state_path, est, opt, gen, step, train, history)
            if on_checkpoint is not None:
                on_checkpoint(est, step, history)
    bar.close()
    if not history or history[-1]["step"] != step:
        evaluate(step)
    est.model.eval()
    if state_path is not None:
        _save_state(state_path, est, opt, gen, step, train, history)
    return est, history


def _to_input(residuals: np.ndarray, cfg: EstimatorConfig, chunk: int = 512) -> torch.Tensor:
    """Resize residuals to the model input once; keep them as uint8 (N, 3, h, w) to save memory."""
    out = []
    for i in range(0, len(residuals), chunk):
        x = preprocess(residuals[i : i + chunk], cfg) * cfg.residual_scale + cfg.residual_offset
        out.append(x.round_().clamp_(0, 255).to(torch.uint8))
    return torch.cat(out)
