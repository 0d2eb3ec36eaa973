"""Simulated sensor instances for sensor randomisation: two GelSight-type sensors never look alike.

A family is a deterministic list of instances (``sensor_instance(family, index)``), each a ``SensorSpec`` and an
optics model drawn from ranges around the GelSight Mini:

- ``train``: the three-light optics over the GelSight Mini or the DIGIT background, or the polynomial (Taxim)
  optics over the GelSight Mini background; lighting gain in [0.7, 1.3]. Index 0 is the nominal GelSight Mini.
- ``unseen``: held out of training: the polynomial optics over the DIGIT background, with a lighting gain of
  1.35-1.7, beyond the training band (the background alone barely changes a residual, so the split also
  holds out a band of lighting).

Both draw light elevation 20-45°, gel stiffness (foundation modulus 0.3-0.55 N/mm³, stiffening 1-3),
sensor noise 0.6-2 grey levels, vignetting 0.15-0.5 and a contact tint 0.5-1.5× the nominal one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controltac_il.config import is_int
from controltac_il.tactile.spec import SensorSpec

FAMILIES = ("train", "unseen")
_FAMILY_SEED = {"train": 71, "unseen": 72}
_LOOKS = {"train": (("three_light", "gelsight_mini"), ("three_light", "digit"), ("polynomial", "gelsight_mini")),
          "unseen": (("polynomial", "digit"),)}
_GAIN = {"train": (0.7, 1.3), "unseen": (1.35, 1.7)}


@dataclass(frozen=True)
class SensorInstance:
    """One simulated sensor: ``name`` (``<family>_<index>``, as datasets record it), spec, optics model."""

    name: str
    spec: SensorSpec
    optics: str


def sensor_instance(family: str, index: int, size: tuple[int, int] | None = None) -> SensorInstance:
    """Instance ``index`` (>= 0) of ``family`` ("train" | "unseen"), rendered at ``size`` = (H, W) pixels
    (default 240×320); a pure function of its arguments."""
    if family not in FAMILIES:
        raise ValueError(f"sensor family must be one of {FAMILIES}, got {family!r}")
    if not is_int(index) or index < 0:
        raise ValueError(f"sensor instance index must be an int >= 0, got {index!r}")
    base = SensorSpec.gelsight_mini()
    if family == "train" and index == 0:
        spec, optics = base, "three_light"
    else:
        rng = np.random.default_rng([_FAMILY_SEED[family], int(index)])
        looks = _LOOKS[family]
        optics, background = looks[int(index) % len(looks)]
        spec = SensorSpec.gelsight_mini(
            background=background, optics_gain=float(rng.uniform(*_GAIN[family])),
            light_elevation_deg=float(rng.uniform(20.0, 45.0)), foundation_modulus=float(rng.uniform(0.3, 0.55)),
            stiffening=float(rng.uniform(1.0, 3.0)), noise_std=float(rng.uniform(0.6, 2.0)),
            vignetting=float(rng.uniform(0.15, 0.5)),
            contact_tint=tuple(float(v) for v in np.asarray(base.contact_tint) * rng.uniform(0.5, 1.5)))
    if size is not None:
        spec = spec.scaled(*size)
    return SensorInstance(f"{family}_{int(index):02d}", spec, optics)


def instance_by_name(name: str, size: tuple[int, int] | None = None) -> SensorInstance:
    """The instance a dataset names (``<family>_<index>``)."""
    family, _, index = str(name).rpartition("_")
    if family not in FAMILIES or not index.isdigit():
        raise ValueError(f"not a sensor instance name (<family>_<index>, family in {FAMILIES}): {name!r}")
    return sensor_instance(family, int(index), size)
