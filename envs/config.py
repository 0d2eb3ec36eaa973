"""Configuration of the peg-in-hole scene: ``PegInHoleConfig``, the project's config idiom (a pydantic
dataclass with ``config=STRICT``, ``controltac_il.config``), validated on construction.

Every invalid field raises one ValueError of one line naming the field(s) and the expected form
(``controltac_il.config.one_line`` of pydantic's errors, see ``one_line_errors``). The field types below
keep numbers honest: booleans must be ``bool`` (not "no" or 1), ints ``int`` (not True or 2.5), numbers
real (not "10") and finite; numbers become floats and sequences tuples.
"""

from __future__ import annotations

import functools
import math
import numbers
from dataclasses import field
from typing import Annotated, Literal

from pydantic import BeforeValidator, Field, ValidationInfo, field_validator, model_validator
from pydantic.dataclasses import dataclass

from controltac_il.config import STRICT, one_line_errors
from controltac_il.tactile.spec import IMAGE_SIDE_PX
from envs.geometry import HOME_TCP, PEG_RADIUS_M, PHYSICS_HZ, TABLE_HALF_SIZE_M, WALL_THICKNESS_M

CAMERAS = ("third_view", "wrist")
SENSORS = ("left", "right")
OPTICS = ("polynomial", "three_light")
CAMERA_LAYOUTS = ("side", "occluding")
EVAL_SEED = 100_000  # first scene seed of every evaluation; demos use seeds below it
DEMO_EPISODES = 20  # scripted-expert demos of the embedded default (train_act.py without --dataset)

# Plausibility bounds of the checks (the scene's dimensions are envs.geometry's)
WORKSPACE_Z_M = (0.0, 0.5)  # plausible TCP heights: on the table up to half a metre above it
AXES = ("x", "y", "z", "yaw")
XY_RANGE_M = 0.15  # peg and hole positions lie within this of the table's centre
# hole_diameter_mm, hole_depth_mm and grasp_depth_mm in mm: the hole clears the peg by 0.25 mm radially.
# 10 <= grasp depth and hole depth <= 60 keep a held peg's bottom (home z + grasp depth - peg length
# >= 80 mm) above the highest rim (base + 60 mm): a peg in hand never starts inserted
BOUNDS_MM = {"hole_diameter_mm": (2000.0 * PEG_RADIUS_M + 0.5, 60.0, f" (the peg is Ø{2000.0 * PEG_RADIUS_M:g} mm)"),
             "hole_depth_mm": (10.0, 60.0, ""),
             "grasp_depth_mm": (10.0, 30.0, " (the gel is 15.2 mm tall)")}


# -- field types. Each check returns the normalised value or raises a message without the field's name
# (``one_line`` puts the name and the value given in front and behind).

def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _flag(value) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"must be True or False, not {type(value).__name__}")
    return value


def _int(value) -> int:
    if not isinstance(value, numbers.Integral) or isinstance(value, bool):
        raise ValueError(f"must be an int, not {type(value).__name__}")
    return int(value)


def finite(unit: str) -> BeforeValidator:
    """A finite real number in ``unit`` (not a bool or a string), as a float."""

    def check(value) -> float:
        if not _is_number(value):
            raise ValueError(f"must be a number ({unit}), not {type(value).__name__}")
        if not math.isfinite(float(value)):
            raise ValueError(f"must be a finite number ({unit})")
        return float(value)

    return BeforeValidator(check)


def _numbers(value, n: int, form: str) -> tuple[float, ...]:
    """``n`` finite real numbers as floats, or a ValueError naming ``form``."""
    try:
        items = tuple(value)
    except TypeError:
        items = ()
    if len(items) != n or not all(_is_number(v) for v in items):
        raise ValueError(f"must be {form}, {n} numbers")
    if not all(math.isfinite(float(v)) for v in items):
        raise ValueError(f"must be finite: {form}")
    return tuple(float(v) for v in items)


def _range(value, low: float = -math.inf, high: float = math.inf) -> tuple[float, float]:
    lo, hi = _numbers(value, 2, "a (low, high) pair")
    if not low <= lo <= hi <= high:
        raise ValueError(f"must satisfy {low:g} <= low <= high <= {high:g}")
    return lo, hi


def bounded_range(low: float = -math.inf, high: float = math.inf):
    """A (low, high) pair of finite floats with ``low_bound <= low <= high <= high_bound``."""
    return Annotated[tuple[float, float], BeforeValidator(functools.partial(_range, low=low, high=high))]


def _xy_range(value) -> tuple[tuple[float, float], tuple[float, float]]:
    try:
        pair = tuple(value)
    except TypeError:
        pair = ()
    if len(pair) != 2:
        raise ValueError("must be ((x_low, x_high), (y_low, y_high)) in m")
    out = []
    for axis, r in zip("xy", pair):
        try:
            out.append(_range(r, -XY_RANGE_M, XY_RANGE_M))
        except ValueError as exc:
            raise ValueError(f"its {axis} range {exc}") from None
    return tuple(out)


def _size(value) -> tuple[int, int]:
    try:
        items = tuple(value)
    except TypeError:
        items = ()
    if len(items) != 2 or not all(isinstance(v, numbers.Integral) and not isinstance(v, bool) for v in items):
        raise ValueError("must be a (height, width) pair of ints")
    h, w = (int(v) for v in items)
    lo, hi = IMAGE_SIDE_PX
    if not (lo <= h <= hi and lo <= w <= hi):
        raise ValueError(f"must be (height, width) in pixels, each in [{lo}, {hi}]")
    return h, w


def _cameras(value) -> tuple[str, ...]:
    form = f"must be a tuple of camera names (a subset of {CAMERAS})"
    if isinstance(value, str):
        raise ValueError(form)
    try:
        names = tuple(value)
    except TypeError:
        raise ValueError(form) from None
    unknown = [c for c in names if c not in CAMERAS]
    if unknown:
        raise ValueError(f"unknown camera {unknown[0]!r}, expected a subset of {CAMERAS}")
    if len(set(names)) != len(names):
        raise ValueError("must not repeat a name")
    return names


def _pose_bound(value) -> tuple[float, float, float, float]:
    """A workspace bound (x, y, z, yaw): finite, x and y over the table, plausible height and yaw."""
    pose = _numbers(value, 4, "(x, y, z in m, yaw in rad)")
    limits = {"x": (-TABLE_HALF_SIZE_M, TABLE_HALF_SIZE_M, "m, over the table"),
              "y": (-TABLE_HALF_SIZE_M, TABLE_HALF_SIZE_M, "m, over the table"),
              "z": (*WORKSPACE_Z_M, "m above the table"), "yaw": (-math.pi, math.pi, "rad")}
    for axis, v in zip(AXES, pose):
        lo, hi, what = limits[axis]
        if not lo <= v <= hi:
            raise ValueError(f"{axis} must be in [{lo:g}, {hi:g}] ({what}), got {v!r}")
    return pose


Flag = Annotated[bool, BeforeValidator(_flag)]
Int = Annotated[int, BeforeValidator(_int)]
Mm = Annotated[float, finite("mm")]
Pixels = Annotated[tuple[int, int], BeforeValidator(_size)]
XYRange = Annotated[tuple[tuple[float, float], tuple[float, float]], BeforeValidator(_xy_range)]
PoseBound = Annotated[tuple[float, float, float, float], BeforeValidator(_pose_bound)]
GripRange = bounded_range(0.5, 15.0)  # above ~15 N the finger servo would no longer saturate on the peg
YawRange = bounded_range(-math.pi, math.pi)
OffsetRange = bounded_range(0.0, 9.0)


def _rect_gap(a: tuple[tuple[float, float], tuple[float, float]],
              b: tuple[tuple[float, float], tuple[float, float]]) -> float:
    """Smallest distance between a point of rectangle ``a`` and one of ``b`` (each ((x0, x1), (y0, y1)))."""
    gaps = [max(0.0, b[k][0] - a[k][1], a[k][0] - b[k][1]) for k in range(2)]
    return math.hypot(*gaps)


@one_line_errors
@dataclass(config=STRICT)
class PegInHoleConfig:
    """Peg-in-hole scene settings. Lengths in the names' units; angles in rad; forces in N.

    cameras: RGB cameras rendered into the observation, a subset of ("third_view", "wrist");
        empty = none rendered (fast physics-only runs).
    camera_size: (height, width) of every camera image in pixels.
    tactile: render one tactile image per finger ("left", "right") into the observation.
    tactile_size: (height, width) of the tactile images, aspect 3:4; the pad keeps the GelSight
        Mini's physical size, so fewer pixels means a coarser pitch.
    tactile_optics: the sensor model's optics, "three_light" (default: the optics the generator's
        training data and the sensor model default to) or "polynomial" (Taxim lookup).
    ray_stride: tactile rays are cast every ``ray_stride`` pixels and the gap to the peg is
        interpolated bilinearly: on the smooth peg surface at 120x160 the map is within 0.0006 /
        0.0016 / 0.003 mm of one ray per pixel at stride 2 / 3 / 4 (same contact mask), at 1/3, 1/8,
        1/18 of the cost.
    hole_diameter_mm: diameter of the receptacle's hole (30 = the paper; 26 = a tight variant);
        the peg is Ø25 mm (the MJCF's geom "peg").
    hole_depth_mm: depth of the hole from rim to floor (paper: 40).
    hole_chamfer_mm: width of the 45° lead-in chamfer at the rim (mm; 0 = sharp rim). A peg whose
        bottom lands within clearance + chamfer of the axis is guided in, as on a machined fixture.
    control_hz: rate of ``step`` calls in Hz, in [1, 500]; physics runs at 500 Hz (``PHYSICS_HZ``: the
        MJCF's 2 ms timestep), so 500 / control_hz substeps per step (must divide evenly).
    max_steps: an episode is truncated after this many control steps.
    grip_force_range_n: grip force (per finger, N) drawn uniformly per episode: the finger servos
        are force-limited at this value, so it sets how hard the gels are pressed.
    peg_xy_range_m: ((x_low, x_high), (y_low, y_high)) where the peg stands at reset: the peg must
        clear the receptacle (hole radius + ``WALL_THICKNESS_M``, a square footprint) of every hole position
        by its radius (``PEG_RADIUS_M``), or an episode could start inserted (refused).
    peg_yaw_range_rad: (low, high) of the peg's yaw at reset (the stripe shows it).
    hole_xy_range_m: ((x_low, x_high), (y_low, y_high)) of the hole's centre at reset.
        Defaults (peg +-10 x +-20 mm, yaw +-45°; hole +-5 mm, like a fixture set by hand) are what
        the cpu-preset ACT learns from 50 demos in minutes: with the peg over 60 x 120 mm at any
        yaw and the hole over 20 x 20 mm it missed the grasp in about half the episodes after
        4000 steps (20 epochs; ACT trains for thousands). Widen them for a GPU-sized study.
    workspace_low / workspace_high: bounds of the end-effector target (x, y, z, yaw): the hand
        actuators' ``ctrlrange`` in the model and so the env's ``action_space``; targets outside are
        clipped and flagged in ``info["clipped"]``. Finite, low < high, x and y over the table (+-0.3 m),
        z in [0, 0.5] m, yaw in [-pi, pi]; it must contain the hand's start (the home keyframe,
        ``envs.geometry.HOME_TCP``, or ``peg_xy_range_m`` with ``peg_in_hand``) and the peg and hole ranges.
    success_depth_mm: the peg counts as inserted when its bottom is this far below the rim and
        its axis is inside the hole.
    tactile_noise: add the sensor model's pixel noise (seeded per episode and step).
    peg_in_hand: start every episode with the peg already grasped (vertical, its top
        ``grasp_depth_mm`` above the TCP) instead of standing on the table; ``peg_xy_range_m`` is
        then where the hand and peg start.
    in_hand_offset_mm: (low, high) of the magnitude of the peg axis' offset from the TCP along the
        gel (the hand's x axis, image columns of the tactile frames), with a random sign; only
        with ``peg_in_hand``. The grip centres the peg between the fingers but not along them.
    grasp_depth_mm: how far below the peg's top the TCP holds it when ``peg_in_hand`` (mm).
    camera_layout: "side" (the paper's third-view camera beside the scene and a wrist camera behind
        the fingers) or "occluding": a top-down third-view camera over a 90 mm wide gripper body
        and a wrist camera on the left finger's back looking down past it, so that the finger and
        the body hide the held peg from both cameras (they still see the hole and the gripper).
    ring_segments: number of wall boxes around the hole (the hole is a regular polygon of this many
        sides inscribed around the circle; 16 keeps the corners within 0.3 mm of it).

    A pydantic dataclass (``config=STRICT``: unknown fields refused). Booleans must be ``bool`` (not "no"
    or 1), ints ``int``, every number finite; each invalid field raises a one-line ValueError naming it
    and the expected form. ``repr`` is stable (``benchmarks.touch_il`` hashes it).
    """

    cameras: Annotated[tuple[str, ...], BeforeValidator(_cameras)] = CAMERAS
    camera_size: Pixels = (96, 128)
    tactile: Flag = True
    tactile_size: Pixels = (120, 160)
    tactile_optics: Literal[OPTICS] = "three_light"
    ray_stride: Annotated[Int, Field(ge=1, le=8)] = 3
    hole_diameter_mm: Mm = 30.0
    hole_depth_mm: Mm = 40.0
    hole_chamfer_mm: Mm = 3.0
    control_hz: Annotated[float, finite("Hz")] = 10.0
    max_steps: Annotated[Int, Field(ge=1, le=1_000_000)] = 120
    grip_force_range_n: GripRange = (3.0, 9.0)
    peg_xy_range_m: XYRange = ((-0.07, -0.05), (-0.02, 0.02))
    peg_yaw_range_rad: YawRange = (-math.pi / 4, math.pi / 4)
    hole_xy_range_m: XYRange = ((0.065, 0.075), (-0.005, 0.005))
    workspace_low: PoseBound = (-0.16, -0.14, 0.012, -math.pi / 2)
    workspace_high: PoseBound = (0.16, 0.14, 0.25, math.pi / 2)
    success_depth_mm: Mm = 30.0
    tactile_noise: Flag = True
    peg_in_hand: Flag = False
    in_hand_offset_mm: OffsetRange = (0.0, 0.0)
    grasp_depth_mm: Mm = 18.0
    camera_layout: Literal[CAMERA_LAYOUTS] = "side"
    ring_segments: Annotated[Int, Field(ge=8, le=64)] = field(default=16, repr=False)

    @classmethod
    def touch_critical(cls, **overrides) -> "PegInHoleConfig":
        """The variant where only touch tells how to insert (``benchmarks.touch_il``).

        The peg starts in the hand, held 5-8 mm off the TCP along the gel with a random sign: more
        than the Ø30 mm hole's 2.5 mm radial clearance plus its 2 mm chamfer, so inserting at the TCP
        (what a policy that ignores the offset learns) lands the peg on the rim. The offset moves
        the contact stripe across the tactile images by 40-63 px (of 160); the ``occluding``
        cameras never see the peg (``benchmarks.touch_il.vision_check`` renders the same hand pose with
        opposite offsets and gets byte-identical camera images), while still showing the hole.
        The grip force per episode, 4-7 N, sets the stripe's width and intensity; the benchmark's
        shifts go below and above it. The peg starts in the hand rather than being picked so that
        the cameras never see where it was grasped and episodes stay short (33 steps for the expert).
        """
        settings = dict(peg_in_hand=True, in_hand_offset_mm=(5.0, 8.0), grasp_depth_mm=18.0,
                        camera_layout="occluding", hole_chamfer_mm=2.0, grip_force_range_n=(4.0, 7.0),
                        peg_xy_range_m=((-0.06, -0.04), (-0.02, 0.02)), peg_yaw_range_rad=(0.0, 0.0),
                        max_steps=60)
        settings.update(overrides)
        return cls(**settings)

    # -- checks that a field's type alone does not make (pydantic runs them in field order, so a check
    # may read the fields above it from ``info.data``; a field missing there had its own error)
    @field_validator("tactile_size")
    @classmethod
    def _gel_aspect(cls, size: tuple[int, int]) -> tuple[int, int]:
        if abs(size[0] / size[1] - 0.75) > 0.015:
            raise ValueError("must keep the GelSight Mini pad's 3:4 (height:width) aspect, e.g. (120, 160)")
        return size

    @field_validator(*BOUNDS_MM)
    @classmethod
    def _bounded_mm(cls, value: float, info: ValidationInfo) -> float:
        low, high, why = BOUNDS_MM[info.field_name]
        if not low <= value <= high:
            raise ValueError(f"must be in [{low:g}, {high:g}]{why}")
        return value

    @field_validator("hole_chamfer_mm", "success_depth_mm")
    @classmethod
    def _within_hole_depth(cls, value: float, info: ValidationInfo) -> float:
        depth = info.data.get("hole_depth_mm")
        if depth is None:
            return value
        if info.field_name == "hole_chamfer_mm" and not 0.0 <= value <= min(8.0, depth / 2):
            raise ValueError("must be in [0, min(8, hole_depth_mm / 2)]")
        if info.field_name == "success_depth_mm" and not 1.0 <= value <= depth:
            raise ValueError(f"must be in [1, hole_depth_mm={depth:g}]")
        return value

    @field_validator("control_hz")
    @classmethod
    def _divides_physics(cls, hz: float) -> float:
        substeps = PHYSICS_HZ / hz if hz > 0 else 0.0
        if not 1.0 <= hz <= PHYSICS_HZ or abs(substeps - round(substeps)) > 1e-9:
            raise ValueError(f"must be a rate in Hz in [1, {PHYSICS_HZ:g}] that divides the {PHYSICS_HZ:g} Hz "
                             f"physics rate evenly (e.g. 10, 25, 50)")
        return hz

    @field_validator("workspace_high")
    @classmethod
    def _above_low(cls, high: tuple[float, ...], info: ValidationInfo) -> tuple[float, ...]:
        low = info.data.get("workspace_low")
        if low is not None and not all(a < b for a, b in zip(low, high)):
            raise ValueError(f"workspace_low / workspace_high must satisfy low < high on every axis "
                             f"(x, y, z in m, yaw in rad), got workspace_low {low}")
        return high

    @field_validator("in_hand_offset_mm")
    @classmethod
    def _needs_peg_in_hand(cls, offset: tuple[float, float], info: ValidationInfo) -> tuple[float, float]:
        if any(offset) and info.data.get("peg_in_hand") is False:
            raise ValueError("needs peg_in_hand=True (otherwise the grasp sets the offset)")
        return offset

    @model_validator(mode="after")
    def _check_start(self) -> "PegInHoleConfig":
        """Refuse starts that break an episode at reset (``envs.peg_in_hole`` success test: the peg's
        bottom centre inside the hole's radius, ``success_depth_mm`` below the rim).

        The hand starts at the home keyframe (with ``peg_in_hand``: at ``peg_xy_range_m``); a start
        outside the workspace is dragged to it while the scene settles, a held peg with it (into the
        hole below). A peg standing on the table starts at its bottom's height, 0, under every rim: one
        whose circle touches the receptacle's square footprint (floor plate and walls) starts inside the
        hole or is pushed into it, so it must clear the footprint of every hole position by its radius.
        """
        low, high = self.workspace_low, self.workspace_high
        for k, axis in enumerate(AXES):
            if self.peg_in_hand and k < 2:
                start, what = self.peg_xy_range_m[k], "peg_xy_range_m (with peg_in_hand the hand starts there)"
            else:
                start, what = (HOME_TCP[k], HOME_TCP[k]), f"the hand's start {axis} = {HOME_TCP[k]:g} (home keyframe)"
            if start[0] < low[k] or start[1] > high[k]:
                field_ = "workspace_low" if start[0] < low[k] else "workspace_high"
                raise ValueError(
                    f"{field_} {axis} [{low[k]:g}, {high[k]:g}] must contain {what} {start}: a start outside the "
                    f"workspace is dragged into it at reset (widen {field_} or move the start)")
        for name in ("peg_xy_range_m", "hole_xy_range_m"):
            for k, axis in enumerate(AXES[:2]):
                r = getattr(self, name)[k]
                if r[0] < low[k] or r[1] > high[k]:
                    raise ValueError(f"{name} {axis} {r} must lie inside the workspace (workspace_low / "
                                     f"workspace_high {axis} [{low[k]:g}, {high[k]:g}]): the hand must reach it")
        if not self.peg_in_hand:
            half = float(self.hole_diameter_mm) / 2000.0 + WALL_THICKNESS_M
            footprint = tuple((lo - half, hi + half) for lo, hi in self.hole_xy_range_m)
            if _rect_gap(self.peg_xy_range_m, footprint) < PEG_RADIUS_M:
                raise ValueError(
                    f"peg_xy_range_m {self.peg_xy_range_m} and hole_xy_range_m {self.hole_xy_range_m} let the peg "
                    f"start on or in the receptacle (an episode could succeed at reset): every peg position must "
                    f"be {PEG_RADIUS_M * 1000:g} mm (its radius) clear of the {2 * half * 1000:g} mm square "
                    f"receptacle around every hole position; move the ranges apart")
        return self

    @property
    def substeps(self) -> int:
        """Physics steps per control step."""
        return int(round(PHYSICS_HZ / float(self.control_hz)))


SCENES = ("default", "touch_critical")


def scene_config(scene: str = "default", **overrides) -> PegInHoleConfig:
    """The named scene's config with ``overrides``: "default" (pick and insert) or "touch_critical"."""
    if scene == "default":
        return PegInHoleConfig(**overrides)
    if scene == "touch_critical":
        return PegInHoleConfig.touch_critical(**overrides)
    raise ValueError(f"scene must be one of {SCENES}, got {scene!r}")
