"""Inverse of the sensor model: tactile residual -> gel height -> re-render at another force.

This is the physics re-render baseline of the generator benchmark (the paper's "simulator" row):

1. invert the optics per pixel: the three-light model gives the RGB change of a surface slope
   (gx, gy); Gauss-Newton on the 3 colour equations recovers the 2 slopes (vignetting undone);
2. integrate the slopes into a height map by Frankot-Chellappa (least squares in Fourier space);
3. treat the recovered height as the penetration, scale it so the mechanics' normal force equals the
   reference force, then scale it again (monotone solve) to the target force;
4. re-render with the sensor model (elastic smoothing, shear, optics, noise).

Only the parametric three-light optics has a closed form to invert; the polynomial lookup is refused.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.optimize import brentq

from controltac_il.tactile import mechanics
from controltac_il.tactile.optics import ThreeLightOptics, vignette
from controltac_il.tactile.residual import OFFSET, contact_mask, to_residual
from controltac_il.tactile.sensor import TactileSensor, check_force
from controltac_il.tactile.spec import SensorSpec


def _check_residual(residual: np.ndarray, spec: SensorSpec) -> np.ndarray:
    r = np.asarray(residual)
    if r.dtype != np.uint8 or r.shape != (spec.height, spec.width, 3):
        raise ValueError(f"residual must be uint8 of shape {(spec.height, spec.width, 3)}, got {r.dtype} {r.shape}")
    return r


def gradients_from_residual(residual: np.ndarray, spec: SensorSpec, optics: ThreeLightOptics,
                            iterations: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Surface slopes (gx along x right, gy along y up; dimensionless), float32 (H, W) each.

    Solves gain·vignette·L·(n(gx, gy) − e_z) = residual − 127 per pixel by Gauss-Newton from the
    small-slope linear solution.
    """
    if not isinstance(optics, ThreeLightOptics):
        raise ValueError(f"inverse optics needs the three_light model, got {getattr(optics, 'name', optics)!r}")
    r = _check_residual(residual, spec)
    c = (r.astype(np.float64) - OFFSET) / (spec.optics_gain * vignette(spec).astype(np.float64))  # (H, W, 3)
    L = optics.lights.astype(np.float64)  # (3 channels, 3 xyz)
    # small slopes: n − e_z ≈ (−gx, −gy, 0)
    A = -L[:, :2]
    p, q = np.moveaxis(c @ np.linalg.pinv(A).T, -1, 0)
    for _ in range(iterations):
        s = 1.0 / np.sqrt(1.0 + p * p + q * q)
        s3 = s**3
        dn = np.stack([-p * s, -q * s, s - 1.0], axis=-1)
        d_dp = np.stack([-s + p * p * s3, p * q * s3, -p * s3], axis=-1)
        d_dq = np.stack([p * q * s3, -s + q * q * s3, -q * s3], axis=-1)
        res = c - dn @ L.T
        jp, jq = d_dp @ L.T, d_dq @ L.T  # (H, W, 3)
        a11, a12, a22 = (jp * jp).sum(-1), (jp * jq).sum(-1), (jq * jq).sum(-1)
        b1, b2 = (jp * res).sum(-1), (jq * res).sum(-1)
        det = a11 * a22 - a12 * a12
        det = np.where(np.abs(det) < 1e-9, 1e-9, det)
        p = np.clip(p + (a22 * b1 - a12 * b2) / det, -3.0, 3.0)
        q = np.clip(q + (a11 * b2 - a12 * b1) / det, -3.0, 3.0)
    return p.astype(np.float32), q.astype(np.float32)


def integrate_gradients(gx: np.ndarray, gy: np.ndarray, mm_per_px: float) -> np.ndarray:
    """Frankot-Chellappa integration of slopes (gx right, gy up) into a height map (mm), mean zero."""
    if gx.shape != gy.shape or gx.ndim != 2:
        raise ValueError(f"gx and gy must be 2-D of one shape, got {gx.shape} and {gy.shape}")
    h, w = gx.shape
    dz_dcol = gx.astype(np.float64) * mm_per_px
    dz_drow = -gy.astype(np.float64) * mm_per_px  # y up = rows decreasing
    # mirror-extend so the periodic FFT sees a continuous field
    ex = np.block([[dz_dcol, -dz_dcol[:, ::-1]], [dz_dcol[::-1], -dz_dcol[::-1, ::-1]]])
    ey = np.block([[dz_drow, dz_drow[:, ::-1]], [-dz_drow[::-1], -dz_drow[::-1, ::-1]]])
    wy, wx = np.meshgrid(np.fft.fftfreq(2 * h) * 2 * np.pi, np.fft.fftfreq(2 * w) * 2 * np.pi, indexing="ij")
    denom = wx**2 + wy**2
    denom[0, 0] = 1.0
    Z = (-1j * wx * np.fft.fft2(ex) - 1j * wy * np.fft.fft2(ey)) / denom
    Z[0, 0] = 0.0
    return np.real(np.fft.ifft2(Z))[:h, :w].astype(np.float32)


def height_from_residual(residual: np.ndarray, spec: SensorSpec, optics: ThreeLightOptics,
                         threshold: float = 12.0) -> np.ndarray:
    """Gel height (mm, >= 0, float32 (H, W)) seen in a residual; zero where there is no contact."""
    r = _check_residual(residual, spec)
    mask = contact_mask(r, threshold=threshold)
    if not mask.any():
        return np.zeros((spec.height, spec.width), np.float32)
    gx, gy = gradients_from_residual(r, spec, optics)
    # slopes outside the (dilated) contact are sensor noise: zero them before integrating
    k = max(3, int(round(spec.smoothing_mm / spec.mm_per_px)) * 2 + 1)
    near = cv2.dilate(mask.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
    height = integrate_gradients(np.where(near, gx, 0), np.where(near, gy, 0), spec.mm_per_px)
    base = np.median(height[~near]) if (~near).any() else float(height.min())
    return np.maximum(height - base, 0.0).astype(np.float32)


def _scale_to_force(pen: np.ndarray, force_n: float, spec: SensorSpec) -> np.ndarray:
    """Multiply ``pen`` by k >= 0 so that the mechanics' normal force equals ``force_n`` (monotone in k)."""
    if force_n <= 0 or not pen.any():
        return np.zeros_like(pen) if force_n <= 0 else pen
    hi = 1.0
    while mechanics.normal_force(pen * hi, spec) < force_n:
        hi *= 2.0
        if hi > 1e6:
            raise ValueError(f"force {force_n} N is not reachable by scaling this penetration")
    k = brentq(lambda s: mechanics.normal_force(pen * s, spec) - force_n, 0.0, hi, xtol=1e-9)
    return (pen * k).astype(np.float32)


def rerender(sensor: TactileSensor, reference_residual: np.ndarray, reference_force, target_force,
             noise_seed: int | None = None) -> np.ndarray:
    """Physics re-render baseline: residual uint8 (H, W, 3) of the reference contact at ``target_force``.

    reference_residual: uint8 (H, W, 3) at the sensor's resolution; forces [Fx, Fy, Fz] N (Fz >= 0).
    """
    if not isinstance(sensor.optics, ThreeLightOptics):
        raise ValueError("rerender needs a TactileSensor with optics='three_light'")
    ref_f = check_force(reference_force)
    tgt_f = check_force(target_force)
    height = height_from_residual(reference_residual, sensor.spec, sensor.optics)
    pen_ref = _scale_to_force(height, ref_f[2], sensor.spec)
    pen_tgt = _scale_to_force(pen_ref, tgt_f[2], sensor.spec) if ref_f[2] > 0 else pen_ref
    image = sensor.render_penetration(pen_tgt, shear=tgt_f[:2], noise_seed=noise_seed)
    return to_residual(image, sensor.background)
