"""Training arrays for the estimator: residuals + force labels, no-contact frames, pose-wise splits."""

from __future__ import annotations

import numpy as np

from controltac_il.tactile.residual import OFFSET


def estimate_noise_std(residuals: np.ndarray, max_images: int = 64, contact_level: float = 10.0) -> float:
    """Sensor noise (grey levels) from residuals (N, H, W, 3): RMS deviation from 127 of pixels
    within ``contact_level`` of it (contact covers a small part of each frame and is excluded)."""
    d = residuals[:: max(1, len(residuals) // max_images)].astype(np.float32) - OFFSET
    d = d[np.abs(d) <= contact_level]
    return float(np.sqrt(np.mean(d * d))) if d.size else 0.0


def no_contact_residuals(n: int, height: int, width: int, noise_std: float, seed: int = 0) -> np.ndarray:
    """``n`` residuals uint8 (n, H, W, 3) of frames without contact: 127 + Gaussian noise of ``noise_std``."""
    if n < 0 or noise_std < 0:
        raise ValueError(f"no_contact_residuals needs n >= 0 and noise_std >= 0, got n={n}, noise_std={noise_std}")
    rng = np.random.default_rng(seed)
    noise = rng.normal(OFFSET, noise_std, size=(n, height, width, 3))
    return np.clip(np.rint(noise), 0, 255).astype(np.uint8)


def with_no_contact(residuals: np.ndarray, forces: np.ndarray, fraction: float, seed: int = 0,
                    noise_std: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Append no-contact frames (label [0, 0, 0] N) making up ``fraction`` of the result."""
    if not 0 <= fraction < 1:
        raise ValueError(f"no-contact fraction must be in [0, 1), got {fraction}")
    n = int(round(len(residuals) * fraction / (1 - fraction)))
    if n == 0:
        return residuals, forces
    std = estimate_noise_std(residuals) if noise_std is None else noise_std
    empty = no_contact_residuals(n, residuals.shape[1], residuals.shape[2], std, seed)
    return (np.concatenate([residuals, empty]),
            np.concatenate([forces, np.zeros((n, 3), np.float32)]).astype(np.float32))


def load_arrays(ds, indices=None, size: tuple[int, int] | None = None, chunk: int = 256,
                progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Residuals uint8 (N, h, w, 3) and forces float32 (N, 3) of a loaded tactile dataset.

    ``ds`` is a ``controltac_il.tactile.dataset.TactileDataset``; ``indices`` selects rows (default
    all); ``size`` = (h, w) resizes each residual (area-averaged) to save memory.
    """
    import cv2
    from tqdm.auto import tqdm

    indices = list(range(len(ds))) if indices is None else list(indices)
    if not indices:
        raise ValueError("load_arrays: no rows selected")
    forces = np.asarray([ds.records[i].force for i in indices], dtype=np.float32)
    out = []
    for i in tqdm(indices, desc="loading residuals", disable=not progress, unit="img"):
        r = ds.residual(i)
        if size is not None and r.shape[:2] != tuple(size):
            r = cv2.resize(r, (size[1], size[0]), interpolation=cv2.INTER_AREA)
        out.append(r)
    return np.stack(out), forces


def split_by_pose(groups: dict, fraction: float, seed: int = 0) -> tuple[list[int], list[int]]:
    """Split row indices so that all images of one contact pose fall on the same side.

    ``groups``: {(object, pose_id): [row indices]}; returns (kept, held_out) with about
    ``fraction`` of the poses of every object held out (at least one when fraction > 0).
    """
    if not 0 <= fraction < 1:
        raise ValueError(f"held-out fraction must be in [0, 1), got {fraction}")
    rng = np.random.default_rng(seed)
    by_object: dict = {}
    for key in sorted(groups):
        by_object.setdefault(key[0], []).append(key)
    kept, held = [], []
    for obj in sorted(by_object):
        keys = by_object[obj]
        n_held = 0 if fraction == 0 else max(1, int(round(fraction * len(keys))))
        n_held = min(n_held, len(keys) - 1)
        order = rng.permutation(len(keys))
        for j, k in enumerate(order):
            (held if j < n_held else kept).extend(groups[keys[k]])
    return sorted(kept), sorted(held)
