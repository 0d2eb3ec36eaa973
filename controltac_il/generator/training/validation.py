"""The generator's validation split: whole objects of a run's own training data held out, and the error the
run chooses its shipped weights by (error of the generated target over the error of copying the reference).

The benchmark's unseen objects and unseen sensor are for reporting only: nothing here reads them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from diffusers.training_utils import EMAModel
from safetensors.torch import load_file, save_file
from tqdm.auto import tqdm

from controltac_il.generator.training.data import PairData
from controltac_il.generator.forces import VALIDATED_RANGE
from controltac_il.io import atomic_path

# Validation pairs per run: enough that the ratio's standard error is a few per cent of it.
VAL_PAIRS = 256


@dataclass(frozen=True)
class ValidationSplit:
    """objects: the held-out object names; ref, tgt: int64 (P,) image indices of the pairs (same contact pose,
    two different frames, both forces in the validated range); delta: float32 (P, 3) ΔF N = F_tgt - F_ref."""

    objects: tuple[str, ...]
    ref: np.ndarray
    tgt: np.ndarray
    delta: np.ndarray


def hold_out_objects(data: PairData, count: int, seed: int, pairs: int = VAL_PAIRS) -> tuple[PairData, ValidationSplit | None]:
    """(training data without ``count`` objects, their validation pairs: ``pairs``, or as many as there are
    distinct ordered pairs); the objects are drawn by ``seed`` from those with a pose group of at least two frames
    in the validated force range. ``count`` = 0: (data, None)."""
    if count == 0:
        return data, None
    usable = [g[~VALIDATED_RANGE.outside(data.forces[g]).any(-1)] for g in data.groups]
    names = sorted({o for o, g in zip(data.group_objects, usable) if len(g) >= 2})
    if count >= len(names):
        raise ValueError(f"val_objects={count} would hold out every object with pairs ({len(names)}): leave some to train on")
    rng = np.random.default_rng([seed, 17])
    held = tuple(sorted(rng.choice(names, size=count, replace=False).tolist()))
    is_val = [o in held for o in data.group_objects]
    train = replace(data, groups=[g for g, v in zip(data.groups, is_val) if not v],
                    group_objects=[o for o, v in zip(data.group_objects, is_val) if not v])
    val_groups = [g for g, v in zip(usable, is_val) if v and len(g) >= 2]
    pairs = min(pairs, distinct_pairs(val_groups))
    pick = rng.integers(0, len(val_groups), size=pairs)
    ref, tgt = np.empty(pairs, np.int64), np.empty(pairs, np.int64)
    for k, gi in enumerate(pick):
        i, j = rng.choice(val_groups[gi], size=2, replace=False)
        ref[k], tgt[k] = i, j
    return train, ValidationSplit(held, ref, tgt, (data.forces[tgt] - data.forces[ref]).astype(np.float32))


def distinct_pairs(groups: list[np.ndarray]) -> int:
    """Ordered pairs of two different frames within the groups."""
    return int(sum(len(g) * (len(g) - 1) for g in groups))


@torch.no_grad()
def generation_error(generator, reference: np.ndarray, target: np.ndarray, delta: np.ndarray,
                     reference_force: np.ndarray | None = None, **masks) -> dict:
    """The generator (a ``ForceGenerator``, its default DDIM steps, seed 0) from ``reference`` to ``target``
    (uint8 (P, H, W, 3) residuals) at ΔF ``delta`` (P, 3) N, from the reference's force ``reference_force`` (P, 3)
    N, which a generator conditioned on it is given (``masks``: stage 2's ``mask=`` target-pose masks): ``{"mse",
    "copy_mse", "ratio_to_copy"}``, MSE in grey levels²."""
    pred = generator.generate(reference, delta, seed=0, reference_force=generator.condition_reference(reference_force),
                              **masks).astype(np.float64)
    tgt = target.astype(np.float64)
    mse, copy = float(((pred - tgt) ** 2).mean()), float(((reference.astype(np.float64) - tgt) ** 2).mean())
    return {"mse": mse, "copy_mse": copy, "ratio_to_copy": mse / max(copy, 1e-12)}


@dataclass
class Validation:
    """A run's validation split: its held-out ``objects``, its number of ``pairs``, and ``error(module)``, a dict
    with ``ratio_to_copy`` (lower is better) for the weights now in the trained module."""

    objects: tuple[str, ...]
    pairs: int
    error: Callable[[torch.nn.Module], dict]


class BestOnValidation:
    """Measures a module's EMA weights at each periodic save and keeps the best (lowest ``ratio_to_copy``) in
    ``path`` (tensors prefixed ``best.``); ``record`` is the run state's ``validation`` metadata (resumable)."""

    def __init__(self, validation: Validation, path: Path, record: dict | None):
        self.validation, self.path = validation, path
        self.record = record or {"objects": list(validation.objects), "pairs": validation.pairs,
                                 "history": [], "best_step": None, "best": None}

    def measure(self, step: int, module: torch.nn.Module, ema: EMAModel) -> None:
        ema.store(module.parameters())
        ema.copy_to(module.parameters())
        try:
            result = {"step": step, **self.validation.error(module)}
            if self.record["best"] is None or result["ratio_to_copy"] < self.record["best"]["ratio_to_copy"]:
                with atomic_path(self.path) as tmp:
                    save_file({"best." + k: v.detach().clone().contiguous() for k, v in module.state_dict().items()}, str(tmp))
                self.record.update(best_step=step, best=result)
        finally:
            ema.restore(module.parameters())
            module.train()
        self.record["history"].append(result)
        tqdm.write(f"step {step}: validation error {result['ratio_to_copy']:.3f}x a copy "
                   f"(best {self.record['best']['ratio_to_copy']:.3f}x at step {self.record['best_step']})")

    def load_best(self, module: torch.nn.Module) -> None:
        module.load_state_dict({k[len("best."):]: v for k, v in load_file(str(self.path)).items()})
