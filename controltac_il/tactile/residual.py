"""Background subtraction as in ControlTac: residual = clip(image − background + 127, 0, 255)."""

from __future__ import annotations

import numpy as np

OFFSET = 127


def _check_image(name: str, a: np.ndarray, shape=None) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype != np.uint8:
        raise ValueError(f"{name} must be uint8 RGB (H, W, 3), got dtype {a.dtype}")
    if a.ndim < 3 or a.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., H, W, 3), got {a.shape}")
    if shape is not None and a.shape[-3:] != shape:
        raise ValueError(f"{name} has shape {a.shape[-3:]}, expected {shape} (the background's)")
    return a


def to_residual(image: np.ndarray, background: np.ndarray) -> np.ndarray:
    """Residual uint8 (..., H, W, 3) of ``image`` against ``background`` (H, W, 3)."""
    bg = _check_image("background", background)
    img = _check_image("image", image, bg.shape[-3:])
    return np.clip(img.astype(np.int16) - bg + OFFSET, 0, 255).astype(np.uint8)


def from_residual(residual: np.ndarray, background: np.ndarray) -> np.ndarray:
    """Image uint8 (..., H, W, 3) from a ``residual`` and its ``background``."""
    bg = _check_image("background", background)
    res = _check_image("residual", residual, bg.shape[-3:])
    return np.clip(res.astype(np.int16) - OFFSET + bg, 0, 255).astype(np.uint8)


def residual_magnitude(residual: np.ndarray) -> np.ndarray:
    """Per-pixel largest channel deviation from the 127 offset, float32 (..., H, W)."""
    res = _check_image("residual", residual)
    return np.abs(res.astype(np.float32) - OFFSET).max(axis=-1)


def contact_mask(residual: np.ndarray, threshold: float = 12.0, min_pixels: int = 0) -> np.ndarray:
    """Contact pixels: residual magnitude above ``threshold`` grey levels (sensor noise ≈ 1–2; a magnitude is at most
    128), bool (..., H, W).

    With ``min_pixels`` > 0, an image with fewer contact pixels than that is treated as no contact.
    """
    number = isinstance(threshold, (int, float, np.number)) and not isinstance(threshold, bool)
    if not number or not 0 <= threshold < 128:
        raise ValueError(f"threshold: expected grey levels in [0, 128) (a residual's magnitude is at most 128), got "
                         f"{threshold!r}")
    if isinstance(min_pixels, bool) or not isinstance(min_pixels, (int, np.integer)) or min_pixels < 0:
        raise ValueError(f"min_pixels: expected an int >= 0, got {min_pixels!r}")
    mask = residual_magnitude(residual) > threshold
    if min_pixels > 0:
        counts = mask.reshape(*mask.shape[:-2], -1).sum(-1)
        mask = mask & (counts >= min_pixels)[..., None, None]
    return mask


def blank(images: np.ndarray) -> np.ndarray:
    """bool (...,): frames (..., H, W, 3) uint8 whose every value is 0 or 255 (a dark, overexposed or dropped
    camera frame): no tactile information to read or to generate from."""
    a = _check_image("image", images)
    return ((a == 0) | (a == 255)).all(axis=(-3, -2, -1))
