"""Configuration of the peg-in-hole scene (one dataclass, validated on construction)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

CAMERAS = ("third_view", "wrist")
SENSORS = ("left", "right")
OPTICS = ("polynomial", "three_light")
CAMERA_LAYOUTS = ("side", "occluding")
EVAL_SEED = 100_000  # first scene seed of every evaluation; demos use seeds below it


def _check_range(name: str, value, low: float = -math.inf, high: float = math.inf) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (low, high) pair of numbers, got {value!r}") from None
    if not (low <= lo <= hi <= high) or not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"{name} must satisfy {low} <= low <= high <= {high}, got {value!r}")
    return lo, hi


def _check_size(name: str, value) -> tuple[int, int]:
    try:
        h, w = (int(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (height, width) pair of ints, got {value!r}") from None
    if h < 8 or w < 8 or h > 2048 or w > 2048:
        raise ValueError(f"{name} must be (height, width) in pixels, each in [8, 2048], got {value!r}")
    return h, w


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
    control_hz: rate of ``step`` calls; physics runs at 500 Hz (timestep 2 ms in the MJCF), so
        500 / control_hz substeps per step (must divide evenly).
    max_steps: an episode is truncated after this many control steps.
    grip_force_range_n: grip force (per finger, N) drawn uniformly per episode: the finger servos
        are force-limited at this value, so it sets how hard the gels are pressed.
    peg_xy_range_m: ((x_low, x_high), (y_low, y_high)) where the peg stands at reset.
    peg_yaw_range_rad: (low, high) of the peg's yaw at reset (the stripe shows it).
    hole_xy_range_m: ((x_low, x_high), (y_low, y_high)) of the hole's centre at reset.
        Defaults (peg +-10 x +-20 mm, yaw +-45°; hole +-5 mm, like a fixture set by hand) are what
        the cpu-preset ACT learns from 50 demos in minutes: with the peg over 60 x 120 mm at any
        yaw and the hole over 20 x 20 mm it missed the grasp in about half the episodes after
        4000 steps (20 epochs; ACT trains for thousands). Widen them for a GPU-sized study.
    workspace_low / workspace_high: bounds of the end-effector target (x, y, z, yaw): the hand
        actuators' ``ctrlrange`` in the model and so the env's ``action_space``; targets outside are
        clipped and flagged in ``info["clipped"]``.
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
        self.cameras = tuple(self.cameras)
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
        if not isinstance(self.ray_stride, int) or not 1 <= self.ray_stride <= 8:
            raise ValueError(f"ray_stride must be an int in [1, 8], got {self.ray_stride!r}")
        if not 25.5 <= float(self.hole_diameter_mm) <= 60.0:
            raise ValueError(
                f"hole_diameter_mm must be in [25.5, 60] (the peg is 25 mm), got {self.hole_diameter_mm!r}")
        if not 10.0 <= float(self.hole_depth_mm) <= 60.0:
            raise ValueError(f"hole_depth_mm must be in [10, 60], got {self.hole_depth_mm!r}")
        if not 0.0 <= float(self.hole_chamfer_mm) <= min(8.0, float(self.hole_depth_mm) / 2):
            raise ValueError(f"hole_chamfer_mm must be in [0, min(8, hole_depth_mm / 2)], got {self.hole_chamfer_mm!r}")
        substeps = 500.0 / float(self.control_hz)
        if float(self.control_hz) <= 0 or abs(substeps - round(substeps)) > 1e-9:
            raise ValueError(f"control_hz must divide the 500 Hz physics rate evenly, got {self.control_hz!r}")
        if not isinstance(self.max_steps, int) or self.max_steps < 1:
            raise ValueError(f"max_steps must be a positive int, got {self.max_steps!r}")
        # grip above ~15 N would no longer saturate the finger servo on the Ø25 mm peg
        self.grip_force_range_n = _check_range("grip_force_range_n", self.grip_force_range_n, 0.5, 15.0)
        self.peg_xy_range_m = tuple(_check_range(f"peg_xy_range_m[{i}]", r, -0.15, 0.15)
                                    for i, r in enumerate(self.peg_xy_range_m))
        self.hole_xy_range_m = tuple(_check_range(f"hole_xy_range_m[{i}]", r, -0.15, 0.15)
                                     for i, r in enumerate(self.hole_xy_range_m))
        if len(self.peg_xy_range_m) != 2 or len(self.hole_xy_range_m) != 2:
            raise ValueError("peg_xy_range_m and hole_xy_range_m must be ((x_low, x_high), (y_low, y_high))")
        self.peg_yaw_range_rad = _check_range("peg_yaw_range_rad", self.peg_yaw_range_rad, -math.pi, math.pi)
        low = tuple(float(v) for v in self.workspace_low)
        high = tuple(float(v) for v in self.workspace_high)
        if len(low) != 4 or len(high) != 4 or not all(a < b for a, b in zip(low, high)):
            raise ValueError(
                "workspace_low / workspace_high must be 4 numbers (x, y, z, yaw) with low < high, "
                f"got {self.workspace_low!r} / {self.workspace_high!r}")
        self.workspace_low, self.workspace_high = low, high
        if not isinstance(self.ring_segments, int) or not 8 <= self.ring_segments <= 64:
            raise ValueError(f"ring_segments must be an int in [8, 64], got {self.ring_segments!r}")
        self.in_hand_offset_mm = _check_range("in_hand_offset_mm", self.in_hand_offset_mm, 0.0, 9.0)
        if any(self.in_hand_offset_mm) and not self.peg_in_hand:
            raise ValueError("in_hand_offset_mm needs peg_in_hand=True (otherwise the grasp sets the offset)")
        if not 10.0 <= float(self.grasp_depth_mm) <= 30.0:
            raise ValueError(f"grasp_depth_mm must be in [10, 30] (the gel is 15.2 mm tall), got {self.grasp_depth_mm!r}")
        if self.camera_layout not in CAMERA_LAYOUTS:
            raise ValueError(f"camera_layout must be one of {CAMERA_LAYOUTS}, got {self.camera_layout!r}")
        if not 1.0 <= float(self.success_depth_mm) <= float(self.hole_depth_mm):
            raise ValueError(
                f"success_depth_mm must be in [1, hole_depth_mm={self.hole_depth_mm}], got {self.success_depth_mm!r}")

    @property
    def substeps(self) -> int:
        """Physics steps per control step."""
        return int(round(500.0 / float(self.control_hz)))


SCENES = ("default", "touch_critical")


def scene_config(scene: str = "default", **overrides) -> PegInHoleConfig:
    """The named scene's config with ``overrides``: "default" (pick and insert) or "touch_critical"."""
    if scene == "default":
        return PegInHoleConfig(**overrides)
    if scene == "touch_critical":
        return PegInHoleConfig.touch_critical(**overrides)
    raise ValueError(f"scene must be one of {SCENES}, got {scene!r}")
