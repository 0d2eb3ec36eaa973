"""``TactileSensor``: press an object with a force, get the tactile image (the facade of this package)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controltac_il.config import is_int
from controltac_il.tactile import mechanics
from controltac_il.tactile.indenters import get_indenter
from controltac_il.tactile.optics import add_noise, contact_tint, load_background, make_optics, vignette
from controltac_il.tactile.residual import to_residual
from controltac_il.tactile.spec import MAX_PLAUSIBLE_FORCE_N, SensorSpec


@dataclass(frozen=True)
class Contact:
    """One rendered contact.

    image, residual: uint8 RGB (H, W, 3). height_mm: gel surface displacement into the sensor, float32
    (H, W). penetration_mm: object imprint, float32 (H, W). mask: geometric contact (penetration > 0),
    bool (H, W), always within the object's footprint over the pad. area_mm2: contact area. depth_mm:
    indentation of the object's highest point on the pad. force: [Fx, Fy, Fz] N the pad carries (Fz
    within the solver tolerance). iterations: force evaluations.

    No contact (Fz = 0, or an object whose footprint misses the pad entirely): empty mask, zero
    penetration, depth 0, the no-contact image (background plus noise) and force (0, 0, 0): a pad that
    touches nothing carries neither normal force nor shear, whatever force was asked for.
    """

    image: np.ndarray
    residual: np.ndarray
    height_mm: np.ndarray
    penetration_mm: np.ndarray
    mask: np.ndarray
    area_mm2: float
    depth_mm: float
    force: tuple[float, float, float]
    iterations: int


def check_force(force) -> tuple[float, float, float]:
    """Validate a force [Fx, Fy, Fz] in N: three finite numbers within ±MAX_PLAUSIBLE_FORCE_N (beyond it the shear
    model's displacement overflows) with Fz >= 0 (pressing)."""
    try:
        f = np.asarray(force, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"force must be [Fx, Fy, Fz] in N, got {force!r}") from None
    if f.shape != (3,):
        raise ValueError(f"force must have 3 components [Fx, Fy, Fz] in N, got {f.size}")
    if not np.isfinite(f).all():
        raise ValueError(f"force must be finite [Fx, Fy, Fz] in N, got {f.tolist()}")
    if np.abs(f).max() > MAX_PLAUSIBLE_FORCE_N:
        raise ValueError(f"force must be within ±{MAX_PLAUSIBLE_FORCE_N:g} N per component (a GelSight's range; mN?), "
                         f"got {f.tolist()}")
    if f[2] < 0:
        raise ValueError(f"force Fz must be >= 0 N (Fz > 0 presses), got {f[2]}")
    return float(f[0]), float(f[1]), float(f[2])


def _check_seed(name: str, seed) -> None:
    """A seed is an int >= 0 (numpy's generators take no other)."""
    if not is_int(seed) or seed < 0:
        raise ValueError(f"{name} must be an int >= 0, got {seed!r}")


class TactileSensor:
    """A simulated GelSight-type sensor.

    Args:
        spec: geometry, mechanics and optics of this instance (default: GelSight Mini).
        optics: "three_light" (parametric, fitted to a GelSight Mini) or "polynomial" (Taxim lookup).
        seed: seeds the sensor noise of calls that give no ``noise_seed``.
    """

    def __init__(self, spec: SensorSpec | None = None, optics: str = "three_light", seed: int = 0):
        if spec is not None and not isinstance(spec, SensorSpec):
            raise ValueError(f"spec: expected a SensorSpec, got {type(spec).__name__}")
        _check_seed("seed", seed)
        self.spec = spec or SensorSpec.gelsight_mini()
        self.optics = make_optics(optics)
        self.background = load_background(self.spec)
        self._vignette = vignette(self.spec)
        self._rng = np.random.default_rng(seed)

    def press(self, obj, pose=(0.0, 0.0, 0.0), force=(0.0, 0.0, 5.0), noise_seed: int | None = None) -> Contact:
        """Press ``obj`` (a name from INDENTERS) at ``pose`` (x_mm, y_mm, theta_rad) with ``force`` [Fx, Fy, Fz] N.

        Only the part of the object over the pad presses; one that misses the pad touches nothing and
        returns a no-contact ``Contact`` with force (0, 0, 0) (see ``Contact``).
        """
        fx, fy, fz = check_force(force)
        relief = get_indenter(obj).heightmap(self.spec, pose)
        sol = mechanics.solve_depth(relief, fz, self.spec)
        pen = mechanics.penetration(relief, sol.depth_mm) if sol.force > 0 else np.zeros_like(relief)
        mask = pen > 0
        if not mask.any():  # nothing touches the gel: no load, no shear
            fx = fy = 0.0
        image, height = self._render(pen, mask, (fx, fy), noise_seed)
        return Contact(
            image=image,
            residual=to_residual(image, self.background),
            height_mm=height,
            penetration_mm=pen,
            mask=mask,
            area_mm2=float(mask.sum() * self.spec.pixel_area_mm2),
            depth_mm=sol.depth_mm,
            force=(fx, fy, sol.force),
            iterations=sol.iterations,
        )

    def render_penetration(self, penetration_mm: np.ndarray, shear=(0.0, 0.0), noise_seed: int | None = None) -> np.ndarray:
        """Tactile image uint8 (H, W, 3) of a given penetration map (mm, (H, W), >= 0), e.g. from ray casting."""
        pen = np.asarray(penetration_mm, dtype=np.float32)
        if pen.shape != (self.spec.height, self.spec.width):
            raise ValueError(f"penetration_mm must have shape {(self.spec.height, self.spec.width)}, got {pen.shape}")
        if not np.isfinite(pen).all() or (pen < 0).any():
            raise ValueError("penetration_mm must be finite and >= 0 mm")
        fx, fy, _ = check_force((*shear, 0.0))
        image, _ = self._render(pen, pen > 0, (fx, fy), noise_seed)
        return image

    def _render(self, pen, mask, shear, noise_seed):
        height = mechanics.gel_surface(pen, self.spec)
        height = mechanics.apply_shear(height, mask, shear, self.spec)
        return self._shade(height, noise_seed), height

    def _shade(self, height, noise_seed):
        if noise_seed is not None:
            _check_seed("noise_seed", noise_seed)
        rng = self._rng if noise_seed is None else np.random.default_rng(noise_seed)
        img = self.background.astype(np.float32) + (self.optics.shade(height, self.spec) + contact_tint(height, self.spec)) * self._vignette
        img = add_noise(img, self.spec.noise_std, rng)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)
