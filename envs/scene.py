"""Build the peg-in-hole MuJoCo model: the MJCF asset plus a receptacle sized from the config.

The receptacle is a base plate and a ring of ``ring_segments`` wall boxes whose inner faces are
tangent to a circle of the hole's diameter (a regular polygon inscribed around the hole): boxes
collide cheaply and exactly, a hole mesh would be decomposed into many convex pieces. The boxes sit
in geom group 3, which cameras do not draw; cameras see one visual tube mesh instead (one draw call
instead of sixteen: the software renderer pays per geom).
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np

ASSET = Path(__file__).resolve().parent / "assets" / "peg_in_hole.xml"

WALL_THICKNESS_M = 0.012  # radial thickness of each wall box
BASE_THICKNESS_M = 0.008  # plate under the hole (its top is the hole's floor)


def build_model(
    hole_diameter_mm: float,
    hole_depth_mm: float,
    ring_segments: int = 16,
    render_size: tuple[int, int] = (96, 128),
) -> mujoco.MjModel:
    """Compile the scene, filling the MJCF's ``receptacle`` body (at the origin; moved per episode).

    hole_diameter_mm: diameter of the inscribed circle of the wall polygon (mm).
    hole_depth_mm: from the rim to the floor (mm).
    render_size: largest (height, width) any camera renders, sizes the offscreen buffer.
    """
    spec = mujoco.MjSpec.from_file(str(ASSET))
    r = hole_diameter_mm / 2000.0
    depth = hole_depth_mm / 1000.0
    body = spec.body("receptacle")
    outer = r + WALL_THICKNESS_M
    static = spec.find_default("static")
    body.add_geom(
        name="hole_floor", type=mujoco.mjtGeom.mjGEOM_BOX, size=[outer, outer, BASE_THICKNESS_M / 2],
        pos=[0.0, 0.0, BASE_THICKNESS_M / 2], contype=1, conaffinity=0, priority=1,
        solref=static.geom.solref, solimp=static.geom.solimp, friction=static.geom.friction,
        rgba=[0.45, 0.35, 0.28, 1.0],
    )
    # half length so neighbouring boxes meet exactly at the outer polygon's vertices (a clean outer
    # 16-gon) and overlap towards the hole (no gaps in the inner polygon the peg slides along)
    half_len = (r + WALL_THICKNESS_M) * math.tan(math.pi / ring_segments)
    for k in range(ring_segments):
        a = 2 * math.pi * k / ring_segments
        c = r + WALL_THICKNESS_M / 2
        body.add_geom(
            name=f"hole_wall{k}", type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[WALL_THICKNESS_M / 2, half_len, depth / 2],
            pos=[c * math.cos(a), c * math.sin(a), BASE_THICKNESS_M + depth / 2],
            quat=[math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)],
            contype=1, conaffinity=0, priority=1, group=3,
            solref=static.geom.solref, solimp=static.geom.solimp, friction=static.geom.friction,
            rgba=[0.55, 0.45, 0.35, 1.0],
        )
    vertices, faces = tube_mesh(r, r + WALL_THICKNESS_M, BASE_THICKNESS_M, BASE_THICKNESS_M + depth, 32)
    spec.add_mesh(name="receptacle_tube", uservert=vertices.ravel().tolist(), userface=faces.ravel().tolist())
    body.add_geom(name="receptacle_visual", type=mujoco.mjtGeom.mjGEOM_MESH, meshname="receptacle_tube",
                  contype=0, conaffinity=0, group=2, density=0.0, rgba=[0.55, 0.45, 0.35, 1.0])
    h, w = render_size
    spec.visual.global_.offheight = max(int(h), 1)
    spec.visual.global_.offwidth = max(int(w), 1)
    return spec.compile()


def tube_mesh(r_in: float, r_out: float, z0: float, z1: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed tube (annular prism) around the z axis: vertices (4n, 3) and outward-facing triangles (8n, 3)."""
    a = 2 * np.pi * np.arange(n) / n
    ring = np.stack([np.cos(a), np.sin(a)], axis=1)
    layers = [(r_in, z0), (r_in, z1), (r_out, z0), (r_out, z1)]  # inner bottom/top, outer bottom/top
    vertices = np.concatenate([np.column_stack([ring * rad, np.full(n, z)]) for rad, z in layers])
    i = np.arange(n)
    j = (i + 1) % n
    ib, it, ob, ot = i, i + n, i + 2 * n, i + 3 * n
    jb, jt, ob2, ot2 = j, j + n, j + 2 * n, j + 3 * n
    quads = [(ob, ob2, ot2, ot), (ib, it, jt, jb), (it, ot, ot2, jt), (ib, jb, ob2, ob)]  # outer, inner, top, bottom
    faces = np.concatenate([np.concatenate([np.column_stack([q0, q1, q2]), np.column_stack([q0, q2, q3])])
                            for q0, q1, q2, q3 in quads])
    return vertices, faces


def rim_height_m(hole_depth_mm: float) -> float:
    """Height of the hole's rim above the table (m)."""
    return BASE_THICKNESS_M + hole_depth_mm / 1000.0
