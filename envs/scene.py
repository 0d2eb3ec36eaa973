"""Build the peg-in-hole MuJoCo model: the MJCF asset plus a receptacle sized from the config.

The receptacle is a base plate and a ring of ``ring_segments`` wall boxes whose inner faces are
tangent to a circle of the hole's diameter (a regular polygon inscribed around the hole): boxes
collide cheaply and exactly, a hole mesh would be decomposed into many convex pieces.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco

ASSET = Path(__file__).resolve().parent / "assets" / "peg_in_hole.xml"

WALL_THICKNESS_M = 0.012  # radial thickness of each wall box
BASE_THICKNESS_M = 0.008  # plate under the hole (its top is the hole's floor)


def build_model(
    hole_diameter_mm: float,
    hole_depth_mm: float,
    ring_segments: int = 16,
    render_size: tuple[int, int] = (96, 128),
) -> mujoco.MjModel:
    """Compile the scene with a receptacle body ``receptacle`` at the origin (moved per episode).

    hole_diameter_mm: diameter of the inscribed circle of the wall polygon (mm).
    hole_depth_mm: from the rim to the floor (mm).
    render_size: largest (height, width) any camera renders, sizes the offscreen buffer.
    """
    spec = mujoco.MjSpec.from_file(str(ASSET))
    r = hole_diameter_mm / 2000.0
    depth = hole_depth_mm / 1000.0
    body = spec.worldbody.add_body(name="receptacle", pos=[0.0, 0.0, 0.0])
    outer = r + WALL_THICKNESS_M
    static = spec.find_default("static")
    body.add_geom(
        name="hole_floor", type=mujoco.mjtGeom.mjGEOM_BOX, size=[outer, outer, BASE_THICKNESS_M / 2],
        pos=[0.0, 0.0, BASE_THICKNESS_M / 2], contype=1, conaffinity=0, priority=1,
        solref=static.geom.solref, solimp=static.geom.solimp, friction=static.geom.friction,
        rgba=[0.45, 0.35, 0.28, 1.0],
    )
    # half length of each wall so neighbouring boxes overlap at the corners (no gaps)
    half_len = (r + WALL_THICKNESS_M) * math.tan(math.pi / ring_segments) + 1e-3
    for k in range(ring_segments):
        a = 2 * math.pi * k / ring_segments
        c = r + WALL_THICKNESS_M / 2
        body.add_geom(
            name=f"hole_wall{k}", type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[WALL_THICKNESS_M / 2, half_len, depth / 2],
            pos=[c * math.cos(a), c * math.sin(a), BASE_THICKNESS_M + depth / 2],
            quat=[math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)],
            contype=1, conaffinity=0, priority=1,
            solref=static.geom.solref, solimp=static.geom.solimp, friction=static.geom.friction,
            rgba=[0.55, 0.45, 0.35, 1.0],
        )
    h, w = render_size
    spec.visual.global_.offheight = max(int(h), 1)
    spec.visual.global_.offwidth = max(int(w), 1)
    return spec.compile()


def rim_height_m(hole_depth_mm: float) -> float:
    """Height of the hole's rim above the table (m)."""
    return BASE_THICKNESS_M + hole_depth_mm / 1000.0
