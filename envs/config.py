"""Configuration of the peg-in-hole scene (one dataclass, validated on construction)."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

CAMERAS = ("third_view", "wrist")
SENSORS = ("left", "right")
OPTICS = ("polynomial", "three_light")
CAMERA_LAYOUTS = ("side", "occluding")
EVAL_SEED = 100_000  # first scene seed of every evaluation; demos use seeds below it


# Geometry of the scene the checks below need (the MJCF and envs.scene / envs.peg_in_hole own these
# values; tests/test_env_scene.py checks that they agree). Importing them would pull in MuJoCo.
PHYSICS_HZ = 500.0  # the MJCF's 2 ms timestep
HOME_TCP = (0.0, 0.0, 0.15, 0.0)  # the "home" keyframe: where the hand starts (x, y, z m, yaw rad)
PEG_RADIUS_M = 0.0125
PEG_HALF_LENGTH_M = 0.04
WALL_THICKNESS_M = 0.012  # the receptacle's wall around the hole; its floor plate is a square of
BASE_THICKNESS_M = 0.008  # half-size hole radius + wall, this thick (the hole's floor)
TABLE_HALF_SIZE_M = 0.3
WORKSPACE_Z_M = (0.0, 0.5)  # plausible TCP heights: on the table up to half a metre above it
AXES = ("x", "y", "z", "yaw")


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _check_number(name: str, value, unit: str) -> float:
    """A finite real number (not a bool or a string); returns it as a float."""
    if not _is_number(value):
        raise ValueError(f"{name} must be a number ({unit}), got {value!r} ({type(value).__name__})")
    if not math.isfinite(float(value)):
        raise ValueError(f"{name} must be a finite number ({unit}), got {value!r}")
    return float(value)


def _check_int(name: str, value, low: int, high: int) -> int:
    if not isinstance(value, numbers.Integral) or isinstance(value, bool) or not low <= value <= high:
        raise ValueError(f"{name} must be an int in [{low}, {high}], got {value!r}")
    return int(value)


def _check_bool(name: str, value) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be True or False, got {value!r} ({type(value).__name__})")
    return value


def _numbers(name: str, value, n: int, form: str) -> tuple[float, ...]:
    """``n`` finite real numbers as floats, or a one-line ValueError naming ``name`` and ``form``."""
    try:
        items = tuple(value)
    except TypeError:
        items = ()
    if len(items) != n or not all(_is_number(v) for v in items):
        raise ValueError(f"{name} must be {form}, {n} numbers, got {value!r}")
    if not all(math.isfinite(float(v)) for v in items):
        raise ValueError(f"{name} must be finite numbers {form}, got {value!r}")
    return tuple(float(v) for v in items)


def _check_range(name: str, value, low: float = -math.inf, high: float = math.inf) -> tuple[float, float]:
    lo, hi = _numbers(name, value, 2, "a (low, high) pair")
    if not low <= lo <= hi <= high:
        raise ValueError(f"{name} must satisfy {low} <= low <= high <= {high}, got {value!r}")
    return lo, hi


def _check_size(name: str, value) -> tuple[int, int]:
    try:
        items = tuple(value)
    except TypeError:
        items = ()
    if len(items) != 2 or not all(isinstance(v, numbers.Integral) and not isinstance(v, bool) for v in items):
        raise ValueError(f"{name} must be a (height, width) pair of ints, got {value!r}")
    h, w = (int(v) for v in items)
    if h < 8 or w < 8 or h > 2048 or w > 2048:
        raise ValueError(f"{name} must be (height, width) in pixels, each in [8, 2048], got {value!r}")
    return h, w


def _rect_gap(a: tuple[tuple[float, float], tuple[float, float]],
              b: tuple[tuple[float, float], tuple[float, float]]) -> float:
    """Smallest distance between a point of rectangle ``a`` and one of ``b`` (each ((x0, x1), (y0, y1)))."""
    gaps = [max(0.0, b[k][0] - a[k][1], a[k][0] - b[k][1]) for k in range(2)]
    return math.hypot(*gaps)


@dataclass
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
        the peg is Ø25 mm.
    hole_depth_mm: depth of the hole from rim to floor (paper: 40).
    hole_chamfer_mm: width of the 45° lead-in chamfer at the rim (mm; 0 = sharp rim). A peg whose
        bottom lands within clearance + chamfer of the axis is guided in, as on a machined fixture.
    control_hz: rate of ``step`` calls in Hz, in [1, 500]; physics runs at 500 Hz (timestep 2 ms in the
        MJCF), so 500 / control_hz substeps per step (must divide evenly).
    max_steps: an episode is truncated after this many control steps.
    grip_force_range_n: grip force (per finger, N) drawn uniformly per episode: the finger servos
        are force-limited at this value, so it sets how hard the gels are pressed.
    peg_xy_range_m: ((x_low, x_high), (y_low, y_high)) where the peg stands at reset: the peg must
        clear the receptacle (hole radius + 12 mm wall, a square footprint) of every hole position by its
        12.5 mm radius, or an episode could start inserted (refused).
    peg_yaw_range_rad: (low, high) of the peg's yaw at reset (the stripe shows it).
    hole_xy_range_m: ((x_low, x_high), (y_low, y_high)) of the hole's centre at reset.
        Defaults (peg +-10 x +-20 mm, yaw +-45°; hole +-5 mm, like a fixture set by hand) are what
        the cpu-preset ACT learns from 50 demos in minutes: with the peg over 60 x 120 mm at any
        yaw and the hole over 20 x 20 mm it missed the grasp in about half the episodes after
        4000 steps (20 epochs; ACT trains for thousands). Widen them for a GPU-sized study.
    workspace_low / workspace_high: bounds of the end-effector target (x, y, z, yaw): the hand
        actuators' ``ctrlrange`` in the model and so the env's ``action_space``; targets outside are
        clipped and flagged in ``info["clipped"]``. Finite, low < high, x and y over the table (+-0.3 m),
        z in [0, 0.5] m, yaw in [-pi, pi]; it must contain the hand's start (the home keyframe
        (0, 0, 0.15 m, 0), or ``peg_xy_range_m`` with ``peg_in_hand``) and the peg and hole ranges.
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

    Booleans must be ``bool`` (not "no" or 1), ints ``int``, every number finite; each invalid field
    raises a one-line ValueError naming it and the expected form.
    """

    cameras: tuple[str, ...] = CAMERAS
    camera_size: tuple[int, int] = (96, 128)
    tactile: bool = True
    tactile_size: tuple[int, int] = (120, 160)
    tactile_optics: str = "three_light"
    ray_stride: int = 3
    hole_diameter_mm: float = 30.0
    hole_depth_mm: float = 40.0
    hole_chamfer_mm: float = 3.0
    control_hz: float = 10.0
    max_steps: int = 120
    grip_force_range_n: tuple[float, float] = (3.0, 9.0)
    peg_xy_range_m: tuple[tuple[float, float], tuple[float, float]] = ((-0.07, -0.05), (-0.02, 0.02))
    peg_yaw_range_rad: tuple[float, float] = (-math.pi / 4, math.pi / 4)
    hole_xy_range_m: tuple[tuple[float, float], tuple[float, float]] = ((0.065, 0.075), (-0.005, 0.005))
    workspace_low: tuple[float, float, float, float] = (-0.16, -0.14, 0.012, -math.pi / 2)
    workspace_high: tuple[float, float, float, float] = (0.16, 0.14, 0.25, math.pi / 2)
    success_depth_mm: float = 30.0
    tactile_noise: bool = True
    peg_in_hand: bool = False
    in_hand_offset_mm: tuple[float, float] = (0.0, 0.0)
    grasp_depth_mm: float = 18.0
    camera_layout: str = "side"
    ring_segments: int = field(default=16, repr=False)

    @classmethod
    def touch_critical(cls, **overrides) -> "PegInHoleConfig":
        """The variant where only touch tells how to insert (issue 19; ``benchmarks.touch_il``).

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

    def __post_init__(self):
        """Validate every field (types first, then ranges, then the scene's geometry); each error is a
        one-line ValueError naming the field(s) and the expected form."""
        for name in ("tactile", "tactile_noise", "peg_in_hand"):
            _check_bool(name, getattr(self, name))
        if isinstance(self.cameras, str):
            raise ValueError(f"cameras must be a tuple of camera names (a subset of {CAMERAS}), got {self.cameras!r}")
        try:
            self.cameras = tuple(self.cameras)
        except TypeError:
            raise ValueError(f"cameras must be a tuple of camera names (a subset of {CAMERAS}), "
                             f"got {self.cameras!r}") from None
        for cam in self.cameras:
            if cam not in CAMERAS:
                raise ValueError(f"cameras: unknown camera {cam!r}, expected a subset of {CAMERAS}")
        if len(set(self.cameras)) != len(self.cameras):
            raise ValueError(f"cameras must not repeat a name, got {self.cameras}")
        self.camera_size = _check_size("camera_size", self.camera_size)
        self.tactile_size = _check_size("tactile_size", self.tactile_size)
        if abs(self.tactile_size[0] / self.tactile_size[1] - 0.75) > 0.015:
            raise ValueError(
                f"tactile_size must keep the GelSight Mini pad's 3:4 (height:width) aspect, e.g. (120, 160), "
                f"got {self.tactile_size}")
        if self.tactile_optics not in OPTICS:
            raise ValueError(f"tactile_optics must be one of {OPTICS}, got {self.tactile_optics!r}")
        self.ray_stride = _check_int("ray_stride", self.ray_stride, 1, 8)
        self.max_steps = _check_int("max_steps", self.max_steps, 1, 1_000_000)
        self.ring_segments = _check_int("ring_segments", self.ring_segments, 8, 64)
        units = {"hole_diameter_mm": "mm", "hole_depth_mm": "mm", "hole_chamfer_mm": "mm", "control_hz": "Hz",
                 "success_depth_mm": "mm", "grasp_depth_mm": "mm"}
        num = {name: _check_number(name, getattr(self, name), unit) for name, unit in units.items()}
        if not 25.5 <= num["hole_diameter_mm"] <= 60.0:
            raise ValueError(
                f"hole_diameter_mm must be in [25.5, 60] (the peg is 25 mm), got {self.hole_diameter_mm!r}")
        if not 10.0 <= num["hole_depth_mm"] <= 60.0:
            raise ValueError(f"hole_depth_mm must be in [10, 60], got {self.hole_depth_mm!r}")
        if not 0.0 <= num["hole_chamfer_mm"] <= min(8.0, num["hole_depth_mm"] / 2):
            raise ValueError(f"hole_chamfer_mm must be in [0, min(8, hole_depth_mm / 2)], got {self.hole_chamfer_mm!r}")
        hz = num["control_hz"]
        substeps = PHYSICS_HZ / hz if hz > 0 else 0.0
        if not 1.0 <= hz <= PHYSICS_HZ or abs(substeps - round(substeps)) > 1e-9:
            raise ValueError(f"control_hz must be a rate in Hz in [1, {PHYSICS_HZ:g}] that divides the "
                             f"{PHYSICS_HZ:g} Hz physics rate evenly (e.g. 10, 25, 50), got {self.control_hz!r}")
        # grip above ~15 N would no longer saturate the finger servo on the Ø25 mm peg
        self.grip_force_range_n = _check_range("grip_force_range_n", self.grip_force_range_n, 0.5, 15.0)
        for name in ("peg_xy_range_m", "hole_xy_range_m"):
            try:
                pair = tuple(getattr(self, name))
            except TypeError:
                pair = ()
            if len(pair) != 2:
                raise ValueError(f"{name} must be ((x_low, x_high), (y_low, y_high)) in m, got {getattr(self, name)!r}")
            setattr(self, name, tuple(_check_range(f"{name}[{i}]", r, -0.15, 0.15) for i, r in enumerate(pair)))
        self.peg_yaw_range_rad = _check_range("peg_yaw_range_rad", self.peg_yaw_range_rad, -math.pi, math.pi)
        self.workspace_low, self.workspace_high = self._check_workspace()
        self.in_hand_offset_mm = _check_range("in_hand_offset_mm", self.in_hand_offset_mm, 0.0, 9.0)
        if any(self.in_hand_offset_mm) and not self.peg_in_hand:
            raise ValueError("in_hand_offset_mm needs peg_in_hand=True (otherwise the grasp sets the offset)")
        # 10 <= grasp depth and hole depth <= 60 keep a held peg's bottom (home z + grasp depth - 80 mm
        # >= 80 mm) above the highest rim (8 + 60 mm): a peg in hand never starts inserted
        if not 10.0 <= num["grasp_depth_mm"] <= 30.0:
            raise ValueError(f"grasp_depth_mm must be in [10, 30] (the gel is 15.2 mm tall), got {self.grasp_depth_mm!r}")
        if self.camera_layout not in CAMERA_LAYOUTS:
            raise ValueError(f"camera_layout must be one of {CAMERA_LAYOUTS}, got {self.camera_layout!r}")
        if not 1.0 <= num["success_depth_mm"] <= num["hole_depth_mm"]:
            raise ValueError(
                f"success_depth_mm must be in [1, hole_depth_mm={self.hole_depth_mm}], got {self.success_depth_mm!r}")
        self._check_start()

    def _check_workspace(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """workspace_low / workspace_high: finite, low < high, over the table, plausible heights and yaw."""
        form = "(x, y, z in m, yaw in rad)"
        bounds = {name: _numbers(name, getattr(self, name), 4, form) for name in ("workspace_low", "workspace_high")}
        low, high = bounds["workspace_low"], bounds["workspace_high"]
        if not all(a < b for a, b in zip(low, high)):
            raise ValueError(f"workspace_low / workspace_high must satisfy low < high on every axis {form}, "
                             f"got {low} / {high}")
        limits = {"x": (-TABLE_HALF_SIZE_M, TABLE_HALF_SIZE_M, "m, over the table"),
                  "y": (-TABLE_HALF_SIZE_M, TABLE_HALF_SIZE_M, "m, over the table"),
                  "z": (*WORKSPACE_Z_M, "m above the table"), "yaw": (-math.pi, math.pi, "rad")}
        for name, values in bounds.items():
            for axis, v in zip(AXES, values):
                lo, hi, what = limits[axis]
                if not lo <= v <= hi:
                    raise ValueError(f"{name} {axis} must be in [{lo:g}, {hi:g}] ({what}), got {v!r} in {values}")
        return low, high

    def _check_start(self) -> None:
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
