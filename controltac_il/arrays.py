"""Tensors and array-likes as NumPy arrays: the one conversion every input check starts from."""

from __future__ import annotations

import numpy as np
import torch


def as_array(value) -> np.ndarray:
    """A tensor or array-like as a NumPy array: no copy for a CPU tensor NumPy has a dtype for; a bfloat16 tensor
    (NumPy has none) as float32, exact, so the caller's dtype check names it as a float array."""
    if not isinstance(value, torch.Tensor):
        return np.asarray(value)
    value = value.detach().cpu()
    return (value.float() if value.dtype == torch.bfloat16 else value).numpy()
