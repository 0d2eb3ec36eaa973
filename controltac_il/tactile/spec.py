"""Sensor specification: geometry, gel mechanics and optics of one GelSight-type sensor instance."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from controltac_il.config import is_real

# smallest and largest side (pixels) of an image rendered or read for training (a robot's cameras: hardware's bound)
IMAGE_SIDE_PX = (8, 2048)
MAX_PLAUSIBLE_FORCE_N = 60.0  # a GelSight Mini is rated to ~25 N: larger forces are in mN or wrong


@dataclass(frozen=True)
class SensorSpec:
    """One sensor instance. Two instances of the same model may differ in lighting, background, stiffness.

    Attributes:
        height, width: image size in pixels (rows, columns). GelSight Mini: 240×320 after the 15 % crop.
        mm_per_px: pixel pitch on the gel in mm at this resolution (GelSight Mini: 0.0634 at 320×240).
        gel_thickness_mm: elastomer thickness; sets the elastic smoothing length and the strain scale.
        foundation_modulus: Winkler foundation stiffness in N/mm³ (pressure per mm of penetration);
            the effective E/thickness of the gel. Default calibrated so a Ø16 mm sphere sinks ≈ 1 mm at 10 N.
        stiffening: dimensionless strain-stiffening coefficient: pressure = k·p·(1 + s·(p/t)²).
        smoothing_mm: length scale of the elastic smoothing of penetration into the gel surface.
        conformity: weight of the exact indenter imprint against its elastic smoothing, in [0, 1].
        shear_compliance_mm_per_n: lateral gel displacement at the contact per newton of shear.
        optics_gain: multiplier on the optical response (lighting brightness of this instance).
        light_elevation_deg: elevation of the three lights above the gel plane (three-light model).
        contact_tint: RGB brightening (grey levels) where the gel is pressed fully: the coating's
            reflectance change under contact, visible even for a flat face with no slope.
        tint_depth_mm: gel displacement at which the tint reaches 63 % of ``contact_tint``.
        vignetting: strength of the radial fall-off of the optical response at the corners, in [0, 1).
        noise_std: standard deviation of additive sensor noise in grey levels.
        background: a shipped background ("gelsight_mini", "digit") or a path to an RGB image.
    """

    height: int = 240
    width: int = 320
    mm_per_px: float = 0.0634
    gel_thickness_mm: float = 3.0
    foundation_modulus: float = 0.4
    stiffening: float = 2.0
    smoothing_mm: float = 0.5
    conformity: float = 0.5
    shear_compliance_mm_per_n: float = 0.25
    optics_gain: float = 1.0
    light_elevation_deg: float = 30.0
    contact_tint: tuple[float, float, float] = (14.0, 8.0, 12.0)
    tint_depth_mm: float = 0.15
    vignetting: float = 0.35
    noise_std: float = 1.2
    background: str = "gelsight_mini"

    def __post_init__(self) -> None:
        for name in ("height", "width"):
            v = getattr(self, name)
            if not isinstance(v, int) or not IMAGE_SIDE_PX[0] <= v <= IMAGE_SIDE_PX[1]:
                raise ValueError(f"SensorSpec.{name} must be an int in {list(IMAGE_SIDE_PX)} pixels, got {v!r}")
        for name in ("mm_per_px", "gel_thickness_mm", "foundation_modulus", "smoothing_mm", "optics_gain", "tint_depth_mm"):
            v = getattr(self, name)
            if not (is_real(v) and v > 0):
                raise ValueError(f"SensorSpec.{name} must be a finite number > 0, got {v!r}")
        for name in ("stiffening", "shear_compliance_mm_per_n", "noise_std"):
            v = getattr(self, name)
            if not (is_real(v) and v >= 0):
                raise ValueError(f"SensorSpec.{name} must be a finite number >= 0, got {v!r}")
        tint = self.contact_tint
        if not (isinstance(tint, (tuple, list)) and len(tint) == 3 and all(is_real(v) for v in tint)):
            raise ValueError(f"SensorSpec.contact_tint must be 3 finite grey levels (R, G, B), got {self.contact_tint!r}")
        if not (is_real(self.conformity) and 0.0 <= self.conformity <= 1.0):
            raise ValueError(f"SensorSpec.conformity must be in [0, 1], got {self.conformity!r}")
        if not (is_real(self.vignetting) and 0.0 <= self.vignetting < 1.0):
            raise ValueError(f"SensorSpec.vignetting must be in [0, 1), got {self.vignetting!r}")
        if not (is_real(self.light_elevation_deg) and 5.0 <= self.light_elevation_deg <= 85.0):
            raise ValueError(f"SensorSpec.light_elevation_deg must be in [5, 85], got {self.light_elevation_deg!r}")

    @classmethod
    def gelsight_mini(cls, **overrides) -> "SensorSpec":
        """GelSight Mini defaults (240×320, 0.0634 mm/px); keyword overrides make another instance."""
        return cls(**overrides)

    def scaled(self, height: int, width: int) -> "SensorSpec":
        """The same physical pad sampled at ``height × width`` pixels (aspect ratio must match)."""
        lo, hi = IMAGE_SIDE_PX
        if not (isinstance(height, int) and isinstance(width, int) and lo <= height <= hi and lo <= width <= hi):
            raise ValueError(f"scaled(height, width) needs ints in [{lo}, {hi}], got {(height, width)!r}")
        if abs(height / width - self.height / self.width) > 0.02:
            raise ValueError(
                f"scaled({height}, {width}) changes the aspect ratio {self.height}:{self.width}; "
                "the pad's physical size is fixed; render at the pad's aspect (e.g. scaled(120, 160)) and "
                "resize the images (the generator resizes to its own 128×160 input, as the paper resizes to 256×320)"
            )
        return dataclasses.replace(self, height=height, width=width, mm_per_px=self.mm_per_px * self.width / width)

    @property
    def pad_size_mm(self) -> tuple[float, float]:
        """Physical pad size (height, width) in mm."""
        return self.height * self.mm_per_px, self.width * self.mm_per_px

    @property
    def pixel_area_mm2(self) -> float:
        return self.mm_per_px**2

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)
