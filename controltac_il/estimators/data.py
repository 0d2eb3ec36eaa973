"""Training arrays for the estimator: residuals + force labels, no-contact frames, pose-wise splits."""

from __future__ import annotations

import numpy as np

from controltac_il.tactile.residual import OFFSET


def estimate_noise_std(residuals: np.ndarray, max_images: int = 64) -> float:
    """Sensor noise (grey levels) from residuals (N, H, W, 3): robust MAD of pixels about 127.

    Contact covers a small part of each frame, so the median deviation is the noise.
    """
    r = residuals[:: max(1, len(residuals) // max_images)].astype(np.float32) - OFFSET
    return float(1.4826 * np.median(np.abs(r)))


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
