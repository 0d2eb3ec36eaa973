"""What a generation call is given, checked, and the one range decision on its forces.

``check_residuals`` / ``check_forces`` / ``check_options`` refuse input the generator was never validated on (non-uint8
or wrongly shaped or blank images, images the resize to the model's size would distort, NaN/inf forces, bad step counts and
seeds); ``decide_forces`` applies ``forces.decide_targets`` (the validated range's one owner) to a request given as
ΔF, ΔF with reference forces, or target forces with reference forces, and warns where the caller gets no decision.
"""

from __future__ import annotations

import warnings
from typing import Sequence

import numpy as np
import torch

from controltac_il.config import AUTO, is_int
from controltac_il.generator.forces import VALIDATED_RANGE, TargetDecision, decide_targets
from controltac_il.tactile.residual import blank

# Largest change of aspect ratio (either way) the resize to the model's image size may make.
MAX_ASPECT_CHANGE = 1.5
DELTA_TARGET = "target force reference_force + delta_force"


def check_residuals(x, name: str, model_hw: tuple[int, int]) -> np.ndarray:
    """uint8 (B, H, W, 3) images (numpy or torch) with B >= 1, H, W >= 8, none blank (``tactile.residual.blank``),
    whose resize to the model's (H, W) changes the aspect ratio by at most ``MAX_ASPECT_CHANGE`` -> the numpy array;
    else ValueError naming ``name``."""
    if isinstance(x, torch.Tensor):  # its dtype named as given (NumPy has no bfloat16)
        if x.dtype != torch.uint8:
            raise ValueError(f"{name} must have dtype uint8 (values 0-255), got {x.dtype}")
        x = x.detach().cpu().numpy()
    if not isinstance(x, np.ndarray):
        raise ValueError(f"{name} must be a uint8 array (B, H, W, 3), got {type(x).__name__}")
    if x.dtype != np.uint8:
        raise ValueError(f"{name} must have dtype uint8 (values 0-255), got {x.dtype}")
    if x.ndim != 4 or x.shape[-1] != 3 or x.shape[0] < 1 or min(x.shape[1:3]) < 8:
        raise ValueError(f"{name} must have shape (B, H, W, 3) with B >= 1 and H, W >= 8, got {x.shape}")
    empty = np.flatnonzero(blank(x))
    if empty.size:  # nothing to condition on: the model would invent a contact
        more = f" (and {empty.size - 1} more)" if empty.size > 1 else ""
        raise ValueError(f"{name}[{empty[0]}]{more} has every value 0 or 255: a dark, overexposed or dropped camera "
                         "frame, not a tactile image; leave it out or keep it real")
    (h, w), (mh, mw) = x.shape[1:3], model_hw
    change = (w / h) / (mw / mh)
    change = max(change, 1.0 / change)
    if change > MAX_ASPECT_CHANGE:  # a 240x20 strip squeezed to 128x160 is a 15x anisotropic resize
        raise ValueError(
            f"{name}: {h}x{w} (HxW) images would be resized to the model's {mh}x{mw} with a {change:.1f}x aspect "
            f"change (at most {MAX_ASPECT_CHANGE:g}x is allowed: the model would see distorted contacts); crop or "
            f"pad them to the model's {mh}:{mw} aspect first")
    return x


def check_forces(f, n: int, name: str) -> np.ndarray:
    """Finite forces (n, 3) [Fx, Fy, Fz] N (numpy, torch or nested lists) -> float64 (n, 3); else ValueError."""
    try:
        raw = np.asarray(f.detach().cpu() if isinstance(f, torch.Tensor) else f)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be a float array (B, 3) in N, got {f!r}") from e
    if raw.dtype.kind not in "fiu":  # never a bool, a string or a complex number read as newtons
        raise ValueError(f"{name} must be real numbers (B, 3) in N, got dtype {raw.dtype}")
    f = raw.astype(np.float64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"{name} must have shape (B, 3) [Fx, Fy, Fz] in N, got {f.shape}")
    if f.shape[0] != n:
        raise ValueError(f"{name} has {f.shape[0]} rows but the batch has {n} reference residuals")
    if not np.all(np.isfinite(f)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return f


def _seed_ok(seed) -> bool:
    """An int torch's generators take (64 bits), never a bool."""
    return is_int(seed) and -2 ** 63 <= seed < 2 ** 63


def check_options(steps, seed: int | Sequence[int], batch_size, n: int, default_steps: int,
                  max_steps: int) -> tuple[int, list[int]]:
    """-> (DDIM steps in [1, max_steps], ``default_steps`` for None; one seed per sample, n ints); ValueError on a
    bad steps, seed or batch_size (a positive int or "auto")."""
    steps = default_steps if steps is None else steps
    if not is_int(steps) or not 1 <= steps <= max_steps:
        raise ValueError(f"steps must be an int in [1, {max_steps}], got {steps!r}")
    if batch_size != AUTO and (not is_int(batch_size) or batch_size < 1):
        raise ValueError(f"batch_size must be a positive int or 'auto', got {batch_size!r}")
    if _seed_ok(seed):
        return int(steps), [int(seed)] * n
    many = isinstance(seed, (Sequence, np.ndarray)) and not isinstance(seed, (str, bytes)) and np.ndim(seed) == 1
    seeds = list(seed) if many else None  # the items themselves: a True stays a bool
    if seeds is None or len(seeds) != n or not all(_seed_ok(s) for s in seeds):
        got = f"{len(seeds)} seeds" if seeds is not None and len(seeds) != n else repr(seed)[:80]
        raise ValueError(f"seed must be one int or {n} ints (one per sample) within 64 bits, got {got}")
    return int(steps), [int(s) for s in seeds]


def decide_forces(out_of_range: str, reference: np.ndarray | None = None, delta: np.ndarray | None = None,
                  target: np.ndarray | None = None, reference_out_of_range: str | None = None,
                  stacklevel: int = 2) -> tuple[TargetDecision, np.ndarray | None]:
    """The range decision of one request, checked forces (B, 3) N: ``target`` (with or without ``reference``), or
    ``delta`` with or without ``reference``. -> (decision, ΔF (B, 3) N to condition on; None for a target without
    reference). A ΔF request warns when it clamps (its caller gets no decision; ``stacklevel`` as warnings.warn)."""
    if target is not None:
        d = decide_targets(target, out_of_range, reference_force=reference,
                           reference_out_of_range=reference_out_of_range)
        return d, None if reference is None else d.target - reference
    if reference is None:  # |ΔF| bounded by the range's span
        what = "delta_force"
        d = decide_targets(delta, out_of_range, VALIDATED_RANGE.delta_range(), what=what)
        fixed = d.target
    else:  # components the decision moved get the new ΔF, the others keep theirs exactly
        what = DELTA_TARGET
        d = decide_targets(reference + delta, out_of_range, what=what, reference_force=reference,
                           reference_out_of_range=reference_out_of_range)
        fixed = np.where(d.target != d.requested, d.target - reference, delta)
    if d.clamped.any():
        warnings.warn(f"clamped {int(d.clamped.sum())} of {len(delta)} samples whose {what} was outside "
                      "the validated range", stacklevel=stacklevel + 1)
    return d, fixed
