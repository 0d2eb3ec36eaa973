"""Contact poses on the pad and rigid moves of binary contact masks (stage 2's spatial condition).

Conventions (the sensor model's, ``indenters.pixel_coordinates``): a pose is (x_mm, y_mm, theta_rad), the
object's origin relative to the pad centre with x right and y *up*, theta counter-clockwise. A mask transform
is ``(dx_px, dy_px, dtheta)``: a rotation by ``dtheta`` rad, counter-clockwise as the image is displayed (row 0
at the top), about the mask's centroid, then a shift of ``dx_px`` columns right and ``dy_px`` rows *down* (image
convention). Pixels are those of the mask's own size.
"""

from __future__ import annotations

import cv2
import numpy as np

from controltac_il.tactile.indenters import check_pose

__all__ = ["check_mask", "mask_centroid", "move_mask", "pose_to_pixel", "transform_between"]


def check_mask(mask, shape: tuple[int, int] | None = None, name: str = "mask") -> np.ndarray:
    """A binary contact mask as bool (H, W): bool or 0/1 values, non-empty, of ``shape`` (H, W) if given."""
    m = np.asarray(mask.detach().cpu() if hasattr(mask, "detach") else mask)
    if m.ndim != 2 or min(m.shape) < 2:
        raise ValueError(f"{name} must be a 2-D (H, W) binary mask, got shape {m.shape}")
    if shape is not None and m.shape != tuple(shape):
        raise ValueError(f"{name} has size {m.shape[0]}x{m.shape[1]} but the images are {shape[0]}x{shape[1]} (HxW)")
    if m.dtype != bool:
        if not np.issubdtype(m.dtype, np.number) or not np.isin(m, (0, 1)).all():
            raise ValueError(f"{name} must be boolean or hold only 0 and 1, got dtype {m.dtype}")
        m = m.astype(bool)
    if not m.any():
        raise ValueError(f"{name} is empty: it marks no contact pixel")
    return m


def mask_centroid(mask: np.ndarray) -> tuple[float, float]:
    """(column, row) of a non-empty mask's centroid, pixels."""
    rows, cols = np.nonzero(mask)
    return float(cols.mean()), float(rows.mean())


def move_mask(mask, transform, scale: float = 1.0, center: tuple[float, float] | None = None,
              name: str = "mask") -> np.ndarray:
    """``mask`` (H, W) moved rigidly by ``transform`` = (dx_px, dy_px, dtheta rad) (module docstring), bool (H, W).

    ``scale`` resizes it about the same centre (robustness tests); ``center`` = (column, row) overrides the
    centroid as the rotation centre. Parts moved off the pad are cut; a mask moved entirely off it is an error.
    """
    m = check_mask(mask, name=name)
    try:
        dx, dy, dtheta = (float(v) for v in transform)
    except (TypeError, ValueError):
        raise ValueError(f"transform must be (dx_px, dy_px, dtheta_rad), got {transform!r}") from None
    if not np.isfinite([dx, dy, dtheta, scale]).all() or scale <= 0:
        raise ValueError(f"transform must be finite and scale > 0, got {transform!r}, scale {scale!r}")
    cx, cy = mask_centroid(m) if center is None else center
    if not np.isfinite([cx, cy]).all():
        raise ValueError(f"center must be a finite (column, row), got {center!r}")
    a = cv2.getRotationMatrix2D((cx, cy), np.degrees(dtheta), scale)
    a[:, 2] += (dx, dy)
    h, w = m.shape
    out = cv2.warpAffine(m.astype(np.uint8), a, (w, h), flags=cv2.INTER_NEAREST, borderValue=0) > 0
    if not out.any():
        raise ValueError(f"transform {tuple(round(v, 3) for v in (dx, dy, dtheta))} moves {name} entirely off the pad")
    return out


def pose_to_pixel(x_mm: float, y_mm: float, mm_per_px: float, size: tuple[int, int]) -> tuple[float, float]:
    """(column, row) of the pad point (x_mm right, y_mm up from the pad centre) in an (H, W) = ``size`` image."""
    if not (np.isfinite([x_mm, y_mm, mm_per_px]).all() and mm_per_px > 0):
        raise ValueError(f"need finite x_mm, y_mm and mm_per_px > 0, got {x_mm!r}, {y_mm!r}, {mm_per_px!r}")
    h, w = size
    return x_mm / mm_per_px + w / 2 - 0.5, h / 2 - y_mm / mm_per_px - 0.5


def transform_between(pose_a, pose_b, mask_a, mm_per_px: float) -> tuple[float, float, float]:
    """The mask transform (dx_px, dy_px, dtheta) that carries a contact at ``pose_a`` to ``pose_b``.

    pose: (x_mm, y_mm, theta_rad); mask_a: the contact mask (H, W) at pose_a (its centroid is the rotation
    centre of the transform); mm_per_px: the mask's pixel pitch.
    """
    m = check_mask(mask_a, name="mask_a")
    pose_a, pose_b = check_pose(pose_a), check_pose(pose_b)
    size = m.shape
    oa, ob = (np.array(pose_to_pixel(p[0], p[1], mm_per_px, size)) for p in (pose_a, pose_b))
    dtheta = float(pose_b[2] - pose_a[2])
    c = np.array(mask_centroid(m))
    # displayed rows point down, so a counter-clockwise turn is (x, y) -> (x cos + y sin, -x sin + y cos)
    cs, sn = np.cos(dtheta), np.sin(dtheta)
    r = c - oa
    moved = ob + np.array([cs * r[0] + sn * r[1], -sn * r[0] + cs * r[1]])
    dx, dy = moved - c
    return float(dx), float(dy), dtheta
