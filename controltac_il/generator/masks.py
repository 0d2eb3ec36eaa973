"""Stage 2's condition: the contact masks at the target pose, given directly or as a rigid move of the object's mask.

A move (dx_px, dy_px, dtheta) rotates by dtheta rad counter-clockwise as displayed about the mask's centroid, then
shifts dx_px columns right and dy_px rows down (``tactile.pose.move_mask``). Every mask is checked
(``tactile.pose.check_mask``): empty masks, masks of another size and moves that leave nothing on the pad are refused.
"""

from __future__ import annotations

import numpy as np
import torch

from controltac_il.tactile.pose import check_mask, move_mask


def stack_masks(value, n: int, hw: tuple[int, int], name: str) -> np.ndarray:
    """One (H, W) mask for every sample or (B, H, W), each checked (``tactile.pose.check_mask``) -> bool (B, H, W)."""
    a = np.asarray(value.detach().cpu() if isinstance(value, torch.Tensor) else value)
    if a.ndim == 2:
        a = np.broadcast_to(a, (n, *a.shape))
    if a.ndim != 3 or a.shape[0] != n:
        raise ValueError(f"{name} must be (H, W) or ({n}, H, W) (one per reference), got shape {a.shape}")
    return np.stack([check_mask(m, hw, f"{name}[{i}]") for i, m in enumerate(a)])


def check_transform(transform, n: int) -> np.ndarray:
    """(3,) for every sample or (n, 3) [dx_px, dy_px, dtheta_rad], finite -> float64 (n, 3); else ValueError."""
    try:
        t = np.asarray(transform, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"transform must be (3,) or ({n}, 3) [dx_px, dy_px, dtheta_rad], got {transform!r}") from None
    t = np.broadcast_to(t, (n, 3)) if t.shape == (3,) else t
    if t.shape != (n, 3) or not np.isfinite(t).all():
        raise ValueError(f"transform must be finite (3,) or ({n}, 3) [dx_px, dy_px, dtheta_rad], got shape {t.shape}")
    return t


def target_masks(n: int, hw: tuple[int, int], mask=None, object_mask=None, transform=None) -> np.ndarray | None:
    """Stage 2's condition: bool (B, H, W) contact masks at the target pose at the references' size hw, or None
    (stage 1). ``mask``: the target pose's mask(s) as given, (H, W) for all or (B, H, W); ``object_mask`` +
    ``transform``: the object's mask(s) at the reference pose moved by (dx_px, dy_px, dtheta) each."""
    if mask is not None and (object_mask is not None or transform is not None):
        raise ValueError("give either mask (at the target pose) or object_mask with transform, not both")
    if (object_mask is None) != (transform is None):
        raise ValueError("object_mask and transform go together (the mask at the reference pose and its move)")
    if mask is not None:
        return stack_masks(mask, n, hw, "mask")
    if object_mask is None:
        return None
    masks = stack_masks(object_mask, n, hw, "object_mask")
    t = check_transform(transform, n)
    return np.stack([move_mask(m, ti, name=f"object_mask[{i}]") for i, (m, ti) in enumerate(zip(masks, t))])
