"""Optics: gel surface height → surface gradients → RGB change over the sensor's background.

Two interchangeable models, both returning the float change in grey levels (H, W, 3), RGB:

* ``ThreeLightOptics``: a parametric model. The gel is lit from the side by three coloured LEDs; each
  colour channel sees the Lambertian shading change L_c·(n − e_z) of the surface normal n under its own
  effective light vector L_c. The default vectors were fitted by least squares to a real GelSight Mini
  frame of a calibration ball (sphere geometry known), so the colour pattern matches the Mini's
  (red/magenta on one side, blue/cyan on the other, green between).
* ``PolynomialOptics``: Taxim's example-based lookup measured on a real GelSight: for each
  (gradient magnitude bin, gradient direction bin) a quadratic polynomial in pixel position per channel.
  The change is lookup(gradient) − lookup(flat).

``contact_tint`` brightens pressed gel (the coating's reflectance under contact), ``vignette`` darkens the optical response towards the corners, ``add_noise`` adds sensor noise; the
sensor facade composes them over the background.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from controltac_il.tactile.spec import SensorSpec

ASSETS = Path(__file__).resolve().parent / "assets"

# Effective light vectors (rows R, G, B; columns x right, y up, z into the sensor), grey levels per unit
# of normal change. Least-squares fit (RMSE 12.9 grey levels) to a real GelSight Mini frame of an Ø8 mm
# calibration ball, with this module's own gel smoothing and vignetting in the loop.
MINI_LIGHTS = np.array(
    [
        [-20.0, 176.0, 13.0],
        [93.0, -5.0, 18.5],
        [20.0, -77.0, 27.5],
    ],
    dtype=np.float32,
)


def surface_gradients(height_mm: np.ndarray, spec: SensorSpec) -> tuple[np.ndarray, np.ndarray]:
    """Surface slopes (dimensionless) of the gel height map along x (right) and y (up)."""
    h = height_mm.astype(np.float32)
    gx = cv2.Sobel(h, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8, borderType=cv2.BORDER_REPLICATE) / spec.mm_per_px
    g_rows = cv2.Sobel(h, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8, borderType=cv2.BORDER_REPLICATE) / spec.mm_per_px
    return gx, -g_rows


class ThreeLightOptics:
    """Parametric three-light Lambertian model with per-channel effective light vectors (3, 3)."""

    name = "three_light"

    def __init__(self, lights: np.ndarray = MINI_LIGHTS):
        lights = np.asarray(lights, dtype=np.float32)
        if lights.shape != (3, 3) or not np.isfinite(lights).all():
            raise ValueError(f"lights must be a finite (3, 3) array (channel × xyz), got shape {lights.shape}")
        self.lights = lights

    def shade(self, height_mm: np.ndarray, spec: SensorSpec) -> np.ndarray:
        gx, gy = surface_gradients(height_mm, spec)
        # the surface bulges towards the camera: normal ∝ (−gx, −gy, 1)
        inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
        dn = cv2.merge([-gx * inv, -gy * inv, inv - 1.0])  # n − e_z, (H, W, 3)
        return cv2.transform(dn, spec.optics_gain * self.lights)  # per pixel: lights @ dn


class PolynomialOptics:
    """Taxim's example-based lookup table (gradient bins × quadratic in pixel position)."""

    name = "polynomial"

    def __init__(self, path: str | Path = ASSETS / "taxim_polycalib.npz"):
        table = np.load(path)
        self.bins = int(table["bins"])
        self.coeffs = np.stack([table["grad_r"], table["grad_g"], table["grad_b"]], axis=2).astype(np.float32)  # (M, D, 3, 6)
        self.flat = self.coeffs[0].mean(axis=0)  # (3, 6): response of a flat gel

    @lru_cache(maxsize=8)
    def _design(self, height: int, width: int) -> np.ndarray:
        """Quadratic terms (x², y², xy, x, y, 1) of pixel positions in the 480×640 calibration frame."""
        ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
        xs, ys = (xs + 0.5) * 640 / width - 0.5, (ys + 0.5) * 480 / height - 0.5
        return np.stack([xs * xs, ys * ys, xs * ys, xs, ys, np.ones_like(xs)], axis=-1)

    def shade(self, height_mm: np.ndarray, spec: SensorSpec) -> np.ndarray:
        gx, gy = surface_gradients(height_mm, spec)
        mag = np.arctan(np.hypot(gx, gy))
        direction = np.arctan2(-gy, gx)  # image rows point down in the calibration frame
        n = self.bins - 1
        mi = np.clip(np.rint(mag / (np.pi / 2) * n), 0, n).astype(np.intp)
        di = np.clip(np.rint((direction + np.pi) / (2 * np.pi) * n), 0, n).astype(np.intp)
        a = self._design(*height_mm.shape)  # (H, W, 6)
        c = self.coeffs[mi, di] - self.flat  # (H, W, 3, 6)
        return spec.optics_gain * np.einsum("hwck,hwk->hwc", c, a)


def make_optics(name: str):
    """Optics model by name: "three_light" or "polynomial"."""
    if name == "three_light":
        return ThreeLightOptics()
    if name == "polynomial":
        return PolynomialOptics()
    raise ValueError(f"optics must be 'three_light' or 'polynomial', got {name!r}")


def contact_tint(height_mm: np.ndarray, spec: SensorSpec) -> np.ndarray:
    """Brightening of pressed gel, (H, W, 3): contact_tint · (1 − exp(−height / tint_depth)); 0 where flat."""
    level = 1.0 - np.exp(-np.maximum(height_mm, 0.0) / spec.tint_depth_mm)
    return level[..., None] * np.asarray(spec.contact_tint, dtype=np.float32)


def vignette(spec: SensorSpec) -> np.ndarray:
    """Radial fall-off of the optical response, (H, W, 1) in (1 − vignetting, 1]."""
    ys, xs = np.mgrid[0:spec.height, 0:spec.width].astype(np.float32)
    r2 = ((xs + 0.5) / spec.width - 0.5) ** 2 + ((ys + 0.5) / spec.height - 0.5) ** 2
    return (1.0 - spec.vignetting * r2 / 0.5)[..., None]


BACKGROUNDS = {
    "gelsight_mini": ASSETS / "background_gelsight_mini.png",  # real GelSight Mini frame (NormalFlow, MIT)
    "digit": ASSETS / "background_digit.jpg",  # real DIGIT frame (TACTO, MIT): another sensor's look
}


def load_background(spec: SensorSpec) -> np.ndarray:
    """The sensor's no-contact frame, uint8 RGB (H, W, 3) resized to the spec's resolution."""
    path = BACKGROUNDS.get(spec.background, Path(spec.background))
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"SensorSpec.background: cannot read an image from {path}")
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    if rgb.shape[:2] != (spec.height, spec.width):
        rgb = cv2.resize(rgb, (spec.width, spec.height), interpolation=cv2.INTER_AREA)
    return rgb


def _gaussian_levels() -> np.ndarray:
    """256 equiprobable quantiles of the unit normal, rescaled to unit variance exactly."""
    from scipy.stats import norm

    q = norm.ppf((np.arange(256) + 0.5) / 256).astype(np.float32)
    return q / q.std()


_GAUSS_LEVELS = _gaussian_levels()


def add_noise(image: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """Additive Gaussian sensor noise of ``std`` grey levels (float image in, float image out).

    Samples one random byte per value and maps it to one of 256 equiprobable normal quantiles: a
    Gaussian quantised far below the image's own 1-grey-level quantisation, about 10× cheaper than
    ``standard_normal`` (benchmarks.sensor), which matters in the 10 Hz scene.
    """
    if std <= 0:
        return image
    idx = np.frombuffer(rng.bytes(image.size), dtype=np.uint8).reshape(image.shape)
    return image + np.float32(std) * _GAUSS_LEVELS[idx]
