"""Tensors and array-likes as NumPy arrays: the one conversion every input check starts from; and a dataset's
item index."""

from __future__ import annotations

import operator

import numpy as np
import torch


def as_array(value) -> np.ndarray:
    """A tensor or array-like as a NumPy array: no copy for a CPU tensor NumPy has a dtype for; a bfloat16 tensor
    (NumPy has none) as float32, exact, so the caller's dtype check names it as a float array."""
    if not isinstance(value, torch.Tensor):
        return np.asarray(value)
    value = value.detach().cpu()
    return (value.float() if value.dtype == torch.bfloat16 else value).numpy()


def as_index(index, dataset: str) -> int:
    """A dataset's item index as an int: an int, a NumPy int or a 0-d integer tensor; TypeError naming ``dataset``
    for anything else (1.7, "3" or True would be another item, silently)."""
    if isinstance(index, bool):
        raise TypeError(f"{dataset} indices are ints, got bool")
    try:
        return operator.index(index)
    except TypeError:
        raise TypeError(f"{dataset} indices are ints, got {type(index).__name__}") from None
