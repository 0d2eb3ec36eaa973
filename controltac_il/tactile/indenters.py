"""Indenters: rigid objects as height fields (mm) placed at a 2-D pose on the sensor pad.

Each object is a relief h(u, v) ≥ 0 in its own frame (u, v in mm, origin at the object's centre):
the height by which its surface stands out towards the gel. Outside its footprint h = 0: nothing
there touches the gel (the holder is not modelled), so a press only ever makes contact within the
object's footprint over the pad, however deep it goes. Objects may extend beyond the pad; only the
part over the pad is sampled, and one whose footprint misses the pad makes no contact at all.

The six training objects follow FeelAnyForce's indenters (cross, slim / thin / medium cylinder, big
sphere, triple cylinder); the held-out ones are shapes the generator never sees in training.
Dimensions are our own choice (FeelAnyForce does not publish CAD here) and are listed per object.
``procedural_<k>`` (k >= 0) names a random training shape (``procedural_indenter``): object diversity
for the generator beyond six indenters, never one of the held-out shapes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from controltac_il.config import is_int
from controltac_il.tactile.spec import SensorSpec

HeightFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Indenter:
    """A named rigid object. ``relief(u, v)`` gives its height in mm at object-frame coordinates (mm)."""

    name: str
    relief: HeightFn
    description: str
    split: str  # "train" or "heldout"

    def heightmap(self, spec: SensorSpec, pose: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
        """Object relief sampled on the sensor's pixel grid: float32 (H, W) in mm.

        ``pose`` = (x_mm, y_mm, theta_rad): the object's centre relative to the pad centre (x right,
        y up) and its rotation about the sensor's z axis.
        """
        x0, y0, theta = check_pose(pose)
        x, y = pixel_coordinates(spec)
        c, s = np.cos(theta), np.sin(theta)
        dx, dy = x - x0, y - y0
        u = c * dx + s * dy
        v = -s * dx + c * dy
        return np.asarray(self.relief(u, v), dtype=np.float32)


def pixel_coordinates(spec: SensorSpec) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (x, y) in mm relative to the pad centre, each (H, W); y points up."""
    p = spec.mm_per_px
    x = (np.arange(spec.width, dtype=np.float64) + 0.5 - spec.width / 2) * p
    y = (spec.height / 2 - np.arange(spec.height, dtype=np.float64) - 0.5) * p
    return np.meshgrid(x, y)


def check_pose(pose) -> tuple[float, float, float]:
    try:
        x, y, theta = (float(v) for v in pose)
    except (TypeError, ValueError):
        raise ValueError(f"pose must be (x_mm, y_mm, theta_rad), got {pose!r}") from None
    if not all(np.isfinite([x, y, theta])):
        raise ValueError(f"pose must be finite (x_mm, y_mm, theta_rad), got {pose!r}")
    return x, y, theta


# --- shape primitives -------------------------------------------------------------------------


def _filleted_plateau(sd: np.ndarray, height: float, fillet: float) -> np.ndarray:
    """Flat-topped relief of ``height`` over the footprint with signed distance ``sd`` (mm, < 0 inside),
    its rim rounded with a quarter circle of radius ``fillet``."""
    t = np.clip(sd + fillet, 0.0, fillet)  # 0 deep inside, fillet at the footprint edge
    h = height - fillet + np.sqrt(np.maximum(fillet**2 - t**2, 0.0))
    return np.where(sd < 0, h, 0.0)


def _box_sd(u: np.ndarray, v: np.ndarray, half_u: float, half_v: float) -> np.ndarray:
    qu, qv = np.abs(u) - half_u, np.abs(v) - half_v
    outside = np.hypot(np.maximum(qu, 0), np.maximum(qv, 0))
    return outside + np.minimum(np.maximum(qu, qv), 0)


def _rounded_box_sd(u, v, half_u, half_v, corner):
    return _box_sd(u, v, half_u - corner, half_v - corner) - corner


def _sphere(u, v, radius, height):
    """Spherical cap of ``radius`` whose top stands ``height`` above the holder plane."""
    r2 = u**2 + v**2
    cap = np.sqrt(np.maximum(radius**2 - r2, 0.0)) - (radius - height)
    return np.maximum(cap, 0.0)


def _lying_cylinder(u, v, radius, half_length, height, end_round=0.5):
    """A cylinder lying along u: height profile across v is circular; ends rounded over ``end_round`` mm."""
    across = np.sqrt(np.maximum(radius**2 - v**2, 0.0)) - (radius - height)
    end = np.clip((half_length - np.abs(u)) / end_round, 0.0, 1.0)
    return np.maximum(across, 0.0) * np.sqrt(end)


# --- the objects --------------------------------------------------------------------------------


def _cross(u, v):
    sd = np.minimum(_box_sd(u, v, 5.0, 1.25), _box_sd(u, v, 1.25, 5.0))
    return _filleted_plateau(sd, 3.0, 0.4)


def _triple_cylinder(u, v):
    return np.maximum.reduce([_lying_cylinder(u, v - off, 1.2, 6.0, 1.2) for off in (-3.5, 0.0, 3.5)])


def _t_shape(u, v):
    sd = np.minimum(_box_sd(u, v - 3.0, 5.0, 1.2), _box_sd(u, v + 1.2, 1.2, 3.0))
    return _filleted_plateau(sd, 3.0, 0.4)


def _usb_c(u, v):
    return _filleted_plateau(_rounded_box_sd(u, v, 4.2, 1.3, 1.2), 3.0, 0.3)


def _flat_ring(u, v):
    r = np.hypot(u, v)
    sd = np.abs(r - 4.0) - 1.0  # annulus between radii 3 and 5 mm
    return _filleted_plateau(sd, 2.0, 0.35)


def _cube_edge(u, v):
    """A 90° cube edge along v (faces at 45° to the gel), tip rounded over ~0.3 mm, 12 mm long."""
    r = 0.3
    ridge = 3.0 + r - np.sqrt(u**2 + r**2)  # hyperbolic rounding of the |u| roof
    return np.maximum(ridge, 0.0) * np.sqrt(np.clip((6.0 - np.abs(v)) / 0.5, 0.0, 1.0))


def _cube_face(u, v):
    return _filleted_plateau(_box_sd(u, v, 12.5, 12.5), 3.0, 0.5)


def _textured_bead(u, v):
    base = _sphere(u, v, 4.0, 2.0)
    bumps = 0.08 * (np.cos(2 * np.pi * u / 0.9) * np.cos(2 * np.pi * v / 0.9))
    return np.where(base > 0, np.maximum(base + bumps, 0.0), 0.0)


INDENTERS: dict[str, Indenter] = {
    ind.name: ind
    for ind in [
        Indenter("cross", _cross, "two 10×2.5 mm bars crossing, flat top 3 mm high, 0.4 mm fillet", "train"),
        Indenter("slim_cylinder", lambda u, v: _lying_cylinder(u, v, 1.0, 7.0, 1.0), "lying cylinder r 1 mm, 14 mm long", "train"),
        Indenter("thin_cylinder", lambda u, v: _lying_cylinder(u, v, 2.0, 7.0, 2.0), "lying cylinder r 2 mm, 14 mm long", "train"),
        Indenter("medium_cylinder", lambda u, v: _lying_cylinder(u, v, 3.5, 8.0, 3.0), "lying cylinder r 3.5 mm, 16 mm long", "train"),
        Indenter("big_sphere", lambda u, v: _sphere(u, v, 8.0, 3.0), "sphere Ø16 mm", "train"),
        Indenter("triple_cylinder", _triple_cylinder, "three parallel lying cylinders r 1.2 mm, 3.5 mm apart", "train"),
        Indenter("t_shape", _t_shape, "T of 10×2.4 and 2.4×6 mm bars, flat top, 0.4 mm fillet", "heldout"),
        Indenter("usb_c", _usb_c, "USB-C plug face 8.4×2.6 mm, rounded corners", "heldout"),
        Indenter("flat_ring", _flat_ring, "flat annulus, radii 3–5 mm", "heldout"),
        Indenter("cube_edge", _cube_edge, "90° cube edge rounded r 0.3 mm, 12 mm long", "heldout"),
        Indenter("cube_face", _cube_face, "flat 25×25 mm cube face (larger than the pad)", "heldout"),
        Indenter("textured_bead", _textured_bead, "sphere Ø8 mm with 0.08 mm bumps every 0.9 mm", "heldout"),
    ]
}
PROCEDURAL_PREFIX = "procedural_"
_PROCEDURAL_SEED = 5081


def procedural_indenter(index: int) -> Indenter:
    """Random training shape ``index`` (>= 0), a pure function of it: the union (pointwise max) of one to three
    primitives, each a spherical cap (radius 2-9 mm, 0.8-3 mm high), a lying cylinder (radius 0.6-4 mm, 2-16 mm
    long) or a filleted elliptical plateau (semi-axes 0.6-5 mm), shifted up to 3.5 mm and rotated at random;
    a quarter of those without a cap carry bumps 0.03-0.1 mm high every 0.6-1.5 mm. No primitive is a ring, a
    T, a box or an edge, and no cap is bumpy: the held-out families (a bumpy cap is ``textured_bead``'s)."""
    if not is_int(index) or index < 0:
        raise ValueError(f"procedural indenter index must be an int >= 0, got {index!r}")
    rng = np.random.default_rng([_PROCEDURAL_SEED, int(index)])
    parts, words = [], []
    for _ in range(int(rng.integers(1, 4))):
        kind = int(rng.integers(3))
        du, dv = rng.uniform(-3.5, 3.5, size=2) if parts else (0.0, 0.0)
        angle = rng.uniform(0, np.pi)
        c, s = np.cos(angle), np.sin(angle)
        if kind == 0:
            r, h = rng.uniform(2.0, 9.0), rng.uniform(0.8, 3.0)
            shape, words = (lambda u, v, r=r, h=min(h, r): _sphere(u, v, r, h)), words + ["cap"]
        elif kind == 1:
            r, half = rng.uniform(0.6, 4.0), rng.uniform(1.0, 8.0)
            shape, words = (lambda u, v, r=r, half=half: _lying_cylinder(u, v, r, half, min(r, 3.0))), words + ["cylinder"]
        else:
            au, av, h = rng.uniform(0.6, 5.0), rng.uniform(0.6, 5.0), rng.uniform(1.0, 3.0)
            fillet = min(rng.uniform(0.2, 0.6) * min(au, av), 0.8 * h)  # the rim stays above the holder
            shape = (lambda u, v, au=au, av=av, h=h, f=fillet:
                     _filleted_plateau((np.hypot(u / au, v / av) - 1.0) * min(au, av), h, f))
            words = words + ["plateau"]
        parts.append(lambda u, v, shape=shape, du=du, dv=dv, c=c, s=s:
                     shape(c * (u - du) + s * (v - dv), -s * (u - du) + c * (v - dv)))
    bumps = None
    if rng.random() < 0.25:
        amp, period = rng.uniform(0.03, 0.1), rng.uniform(0.6, 1.5)
        if "cap" not in words:  # a bumpy cap is the held-out textured bead's family: never drawn
            bumps, words = (amp, period), words + ["bumps"]

    def relief(u, v):
        h = np.maximum.reduce([part(u, v) for part in parts])
        if bumps is None:
            return h
        texture = bumps[0] * np.cos(2 * np.pi * u / bumps[1]) * np.cos(2 * np.pi * v / bumps[1])
        return np.where(h > 0, np.maximum(h + texture, 0.0), 0.0)

    return Indenter(f"{PROCEDURAL_PREFIX}{int(index):04d}", relief, "random union of " + ", ".join(words), "procedural")


def procedural_objects(count: int) -> tuple[str, ...]:
    """Names of the first ``count`` procedural shapes."""
    return tuple(f"{PROCEDURAL_PREFIX}{k:04d}" for k in range(count))


TRAIN_OBJECTS: tuple[str, ...] = tuple(n for n, i in INDENTERS.items() if i.split == "train")
HELDOUT_OBJECTS: tuple[str, ...] = tuple(n for n, i in INDENTERS.items() if i.split == "heldout")


def get_indenter(name: str) -> Indenter:
    """The indenter called ``name``; ValueError listing the known names otherwise."""
    if isinstance(name, Indenter):
        return name
    if isinstance(name, str) and name.startswith(PROCEDURAL_PREFIX) and name[len(PROCEDURAL_PREFIX):].isdigit():
        return procedural_indenter(int(name[len(PROCEDURAL_PREFIX):]))
    try:
        return INDENTERS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown object {name!r}; expected one of {sorted(INDENTERS)} "
                         f"or {PROCEDURAL_PREFIX}<k>") from None
