"""Gel mechanics: normal force → indentation depth, penetration → gel surface, shear → lateral shift.

Model: a Winkler elastic foundation with strain stiffening. At penetration p (mm) the gel pushes back
with pressure q = k·p·(1 + s·(p/t)²) (k: foundation modulus, N/mm³; t: gel thickness; s: stiffening),
so the normal force F(d) = Σ q·A_px is continuous and non-decreasing in the indentation depth d, and
strictly increasing once in contact. The depth for a target force is found by bracketing and Brent's
method (``scipy.optimize.brentq``) to a force tolerance, never by a fixed-step search.

The gel surface is not the hard imprint of the object: it is a blend of the imprint and its elastic
smoothing (a Gaussian of ``smoothing_mm``), so the gel slopes down around the contact as a real
elastomer does. Shear shifts the surface laterally around the contact by a compliance × force field
that decays away from the contact over the gel thickness.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np
from scipy.optimize import brentq

from controltac_il.tactile.spec import SensorSpec

FORCE_RTOL = 1e-4  # relative force tolerance of the depth solve
FORCE_ATOL = 1e-7  # N


@dataclass(frozen=True)
class DepthSolution:
    """Indentation depth (mm) reaching ``force`` (N) within tolerance, and the solver's cost."""

    depth_mm: float
    force: float
    iterations: int


def penetration(relief: np.ndarray, depth_mm: float) -> np.ndarray:
    """Penetration map (mm) when the highest visible point of ``relief`` sinks ``depth_mm`` into the gel.

    Only the object touches the gel: pixels outside its footprint (relief <= 0) never penetrate, however
    deep it is pressed, so a relief with no footprint on the pad gives all zeros.
    """
    footprint = relief > 0
    if not footprint.any():
        return np.zeros(relief.shape, np.float32)
    top = float(relief[footprint].max())
    return np.where(footprint, np.maximum(relief - (top - depth_mm), 0.0), 0.0).astype(np.float32)


def pressure(pen_mm: np.ndarray, spec: SensorSpec) -> np.ndarray:
    """Contact pressure (N/mm²) at penetration ``pen_mm`` (mm)."""
    strain = pen_mm / spec.gel_thickness_mm
    return spec.foundation_modulus * pen_mm * (1.0 + spec.stiffening * strain**2)


def normal_force(pen_mm: np.ndarray, spec: SensorSpec) -> float:
    """Total normal force (N) of a penetration map."""
    return float(pressure(pen_mm, spec).sum() * spec.pixel_area_mm2)


def solve_depth(relief: np.ndarray, force_n: float, spec: SensorSpec, max_depth_mm: float = 50.0) -> DepthSolution:
    """Depth (mm) at which ``relief`` presses with ``force_n`` newtons.

    F(d) is continuous and non-decreasing; the root is bracketed by doubling from a first guess and
    refined with Brent's method to |F − force| ≤ FORCE_RTOL·force + FORCE_ATOL. Only the object's
    footprint (relief > 0) presses (see ``penetration``); a relief with no footprint on the pad (the
    object misses it) carries no force: depth 0, force 0, whatever ``force_n``.
    """
    if not (np.isfinite(force_n) and force_n >= 0):
        raise ValueError(f"force Fz must be a finite number >= 0 N, got {force_n!r}")
    heights = np.sort(relief[relief > 0].astype(np.float64))[::-1]
    if force_n == 0.0 or heights.size == 0:
        return DepthSolution(0.0, 0.0, 0)
    top = heights[0]
    area = spec.pixel_area_mm2

    def force_at(d: float) -> float:
        n = np.searchsorted(-heights, -(top - d), side="left")  # pixels with h > top - d
        p = heights[:n] - (top - d)
        return float((spec.foundation_modulus * p * (1.0 + spec.stiffening * (p / spec.gel_thickness_mm) ** 2)).sum() * area)

    iterations = 0
    hi = 0.05
    f_hi = force_at(hi)
    while f_hi < force_n:
        hi *= 2.0
        iterations += 1
        if hi > max_depth_mm:
            raise ValueError(f"force {force_n} N is not reached within {max_depth_mm} mm of indentation")
        f_hi = force_at(hi)
    tol = FORCE_RTOL * force_n + FORCE_ATOL
    if abs(f_hi - force_n) <= tol:
        return DepthSolution(hi, f_hi, iterations + 1)
    depth, info = brentq(lambda d: force_at(d) - force_n, 0.0, hi, xtol=1e-9, rtol=1e-10, full_output=True)
    return DepthSolution(float(depth), force_at(depth), iterations + 1 + info.function_calls)


def smooth(field: np.ndarray, sigma_px: float, border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
    """Gaussian smoothing of a 2-D float field; wide kernels run on a subsampled grid (the result is
    smooth on that scale anyway), so the cost stays flat as sigma grows."""
    field = field.astype(np.float32, copy=False)
    factor = int(min(8, sigma_px // 3))
    if factor < 2:
        return cv2.GaussianBlur(field, (0, 0), sigmaX=sigma_px, borderType=border)
    h, w = field.shape
    small = cv2.resize(field, (max(1, w // factor), max(1, h // factor)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), sigmaX=sigma_px / factor, borderType=border)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def gel_surface(pen_mm: np.ndarray, spec: SensorSpec) -> np.ndarray:
    """Gel surface displacement (mm, into the sensor) for a penetration map: imprint blended with its
    elastic smoothing. float32 (H, W)."""
    sigma_px = spec.smoothing_mm / spec.mm_per_px
    pen = pen_mm.astype(np.float32, copy=False)
    return spec.conformity * pen + (1.0 - spec.conformity) * smooth(pen, sigma_px)


@lru_cache(maxsize=8)
def _pixel_grid(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = np.indices((height, width), dtype=np.float32)
    rows.flags.writeable = cols.flags.writeable = False
    return rows, cols


def apply_shear(surface_mm: np.ndarray, contact: np.ndarray, shear_n: tuple[float, float], spec: SensorSpec) -> np.ndarray:
    """Shift the gel surface laterally by shear (Fx, Fy) N around the contact ``contact`` (bool (H, W)).

    The displacement is compliance·F where the gel sticks to the object, decaying outside over the
    gel thickness. x is image right, y is image up.
    """
    fx, fy = (float(v) for v in shear_n)
    if (fx == 0.0 and fy == 0.0) or not contact.any():
        return surface_mm
    sigma_px = spec.gel_thickness_mm / spec.mm_per_px / 2
    w = smooth(contact.astype(np.float32), sigma_px, border=cv2.BORDER_CONSTANT)
    w = np.maximum(w / max(float(w.max()), 1e-6), contact.astype(np.float32))
    dx_px = spec.shear_compliance_mm_per_n * fx / spec.mm_per_px * w
    dy_px = -spec.shear_compliance_mm_per_n * fy / spec.mm_per_px * w  # y up = rows decreasing
    rows, cols = _pixel_grid(*surface_mm.shape)
    return cv2.remap(surface_mm, cols - dx_px, rows - dy_px, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
