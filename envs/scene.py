"""Build the peg-in-hole MuJoCo model: the MJCF assets plus a receptacle sized from the config.

assets/peg_in_hole.xml is the scene (table, peg, third-view camera, the "home" keyframe); it includes
assets/tactile_gripper.xml, the robot on its own (hand servos, fingers, gels, wrist camera, sites
"tcp" and "<finger>_sensor"), in the MuJoCo Menagerie layout: default classes for visual and
collision geoms and every repeated setting, actuator ``ctrlrange`` bounding every command
(``build_model`` writes the config's workspace into the hand servos' ranges).

The receptacle is a base plate and a ring of ``ring_segments`` wall boxes whose inner faces are
tangent to a circle of the hole's diameter (a regular polygon inscribed around the hole): boxes
collide cheaply and exactly, a hole mesh would be decomposed into many convex pieces. A 45° lead-in
chamfer at the rim, as machined fixtures have, is a second ring of boxes tilted by 45° whose inner
faces run from the hole's radius ``chamfer`` below the rim to ``chamfer`` further out at the rim (the
walls above its lower edge step back so that nothing juts into the slope). The boxes sit
in geom group 3, which cameras do not draw; cameras see one visual tube mesh instead (one draw call
instead of sixteen: the software renderer pays per geom).
"""

from __future__ import annotations

import math

import numpy as np

from controltac_il.extras import require
from envs.geometry import BASE_THICKNESS_M, HAND_JOINTS, SCENE_XML, WALL_THICKNESS_M

mujoco = require("mujoco", "sim", "the MuJoCo scene")

ASSET = SCENE_XML
HAND_ACTUATORS = HAND_JOINTS  # the gripper's pose servos (each named after its joint), in action order


def build_model(
    hole_diameter_mm: float,
    hole_depth_mm: float,
    ring_segments: int = 16,
    render_size: tuple[int, int] = (96, 128),
    chamfer_mm: float = 0.0,
    camera_layout: str = "side",
    workspace: tuple[tuple[float, ...], tuple[float, ...]] | None = None,
) -> mujoco.MjModel:
    """Compile the scene (assets/peg_in_hole.xml, which includes the gripper, assets/tactile_gripper.xml),
    filling the MJCF's ``receptacle`` body (at the origin; moved per episode).

    hole_diameter_mm: diameter of the inscribed circle of the wall polygon (mm).
    hole_depth_mm: from the rim to the floor (mm).
    chamfer_mm: width (= height) of the 45° lead-in chamfer at the rim (mm); 0 = a sharp rim.
    render_size: largest (height, width) any camera renders, sizes the offscreen buffer.
    camera_layout: "side" (the MJCF's cameras) or "occluding" (see ``occlude_held_peg``).
    workspace: ((x, y, z, yaw) low, (x, y, z, yaw) high) bounds of the hand's servo targets, written
        into the hand actuators' ``ctrlrange``; None keeps the gripper MJCF's reach.
    """
    spec = mujoco.MjSpec.from_file(str(ASSET))
    if camera_layout == "occluding":
        occlude_held_peg(spec)
    elif camera_layout != "side":
        raise ValueError(f"camera_layout must be 'side' or 'occluding', got {camera_layout!r}")
    if workspace is not None:
        for k, name in enumerate(HAND_ACTUATORS):
            spec.actuator(name).ctrlrange = [float(workspace[0][k]), float(workspace[1][k])]
    add_receptacle(spec, hole_diameter_mm / 2000.0, hole_depth_mm / 1000.0, ring_segments, chamfer_mm / 1000.0)
    h, w = render_size
    spec.visual.global_.offheight = max(int(h), 1)
    spec.visual.global_.offwidth = max(int(w), 1)
    return spec.compile()


def add_receptacle(spec: mujoco.MjSpec, r: float, depth: float, ring_segments: int, c: float) -> None:
    """Fill the ``receptacle`` body: floor plate (drawn, group 0), wall ring (and chamfer ring when ``c`` > 0) of
    collision boxes (class "static", group 3) and the visual tube. r: hole radius, depth: rim to
    floor, c: chamfer width (m)."""
    body = spec.body("receptacle")
    outer = r + WALL_THICKNESS_M
    static = spec.find_default("static")
    body.add_geom(default=static, name="hole_floor", type=mujoco.mjtGeom.mjGEOM_BOX,
                  size=[outer, outer, BASE_THICKNESS_M / 2], pos=[0.0, 0.0, BASE_THICKNESS_M / 2],
                  rgba=[0.45, 0.35, 0.28, 1.0])
    # half length so neighbouring boxes meet exactly at the outer polygon's vertices (a clean outer
    # 16-gon) and overlap towards the hole (no gaps in the inner polygon the peg slides along)
    half_len = (r + WALL_THICKNESS_M) * math.tan(math.pi / ring_segments)
    wall = dict(default=static, type=mujoco.mjtGeom.mjGEOM_BOX, group=3)
    for k in range(ring_segments):
        a = 2 * math.pi * k / ring_segments
        radial, yaw = np.array([math.cos(a), math.sin(a)]), [math.cos(a / 2), 0.0, 0.0, math.sin(a / 2)]
        # (inner radius, bottom, top) of the wall boxes: full height, or stepped back above the chamfer
        rings = [(r, BASE_THICKNESS_M, BASE_THICKNESS_M + depth - c)]
        if c > 0:
            rings.append((r + c, BASE_THICKNESS_M + depth - c, BASE_THICKNESS_M + depth))
        for j, (r_in, z0, z1) in enumerate(rings):
            thick = r + WALL_THICKNESS_M - r_in
            body.add_geom(name=f"hole_wall{k}" if j == 0 else f"hole_wall_top{k}",
                          size=[thick / 2, half_len, (z1 - z0) / 2],
                          pos=[*((r_in + thick / 2) * radial), (z0 + z1) / 2], quat=yaw, **wall)
        if c > 0:
            # slab whose inner face is the slope from (r, rim - c) to (r + c, rim); it lies on the
            # wall side of the slope (normal (+radial, -z) / sqrt 2), so it never rises above the rim
            t = WALL_THICKNESS_M / 2
            mid = np.array([r + c / 2, BASE_THICKNESS_M + depth - c / 2]) + t / 2 * np.array([1, -1]) / math.sqrt(2)
            quat = np.zeros(4)
            mujoco.mju_mulQuat(quat, np.array(yaw), np.array([math.cos(math.pi / 8), 0.0, math.sin(math.pi / 8), 0.0]))
            body.add_geom(name=f"hole_chamfer{k}", size=[t / 2, half_len, c / math.sqrt(2)],
                          pos=[*(mid[0] * radial), mid[1]], quat=quat, **wall)
    vertices, faces = tube_mesh(r, r + WALL_THICKNESS_M, BASE_THICKNESS_M, BASE_THICKNESS_M + depth, 32, chamfer=c)
    spec.add_mesh(name="receptacle_tube", uservert=vertices.ravel().tolist(), userface=faces.ravel().tolist())
    body.add_geom(default=spec.find_default("scene_visual"), name="receptacle_visual",
                  type=mujoco.mjtGeom.mjGEOM_MESH, meshname="receptacle_tube", density=0.0,
                  rgba=[0.55, 0.45, 0.35, 1.0])


def occlude_held_peg(spec: mujoco.MjSpec) -> None:
    """Place the cameras so that neither sees a peg held between the fingers.

    third_view: 0.9 m above the table looking straight down (image up = world +y), fovy 15°: the
    whole workspace at 1.9 mm per pixel (96x128), the hole in plain view. The gripper body (palm)
    is widened to 90 x 90 mm, which covers a held peg 8 mm off-centre from this camera anywhere over
    the workspace (its lowest point is 0.11 m below the palm; rays slant by at most 0.13).
    wrist: on the back of the left finger, 2.5 mm out from it, looking down: the finger's back face
    (24 x 62 mm) hides everything on the peg's side of it, and the camera sees the table, the hole's
    outer ring and the gripper body on the other side.
    """
    cam = spec.camera("third_view")
    cam.pos = [0.01, 0.0, 0.9]
    cam.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT  # the MJCF gives xyaxes; use quat instead
    cam.quat = [1.0, 0.0, 0.0, 0.0]
    cam.fovy = 15.0
    spec.geom("palm").size = [0.045, 0.045, 0.01]
    spec.delete(spec.camera("wrist"))
    spec.body("left_finger").add_camera(name="wrist", pos=[0.0, 0.0135, 0.045], quat=[1.0, 0.0, 0.0, 0.0],
                                        fovy=80.0)


def tube_mesh(r_in: float, r_out: float, z0: float, z1: float, n: int,
              chamfer: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Closed tube (annular prism) around the z axis, its inner top edge chamfered by ``chamfer`` (m)
    at 45°: the (radius, z) profile revolved in ``n`` steps. Vertices (k n, 3) and outward-facing
    triangles (2 k n, 3), k = 4 profile corners (5 with a chamfer)."""
    # profile counter-clockwise in the (radius, z) half-plane: bottom, outside, top, inside
    profile = [(r_in, z0), (r_out, z0), (r_out, z1)]
    profile += [(r_in + chamfer, z1), (r_in, z1 - chamfer)] if chamfer > 0 else [(r_in, z1)]
    a = 2 * np.pi * np.arange(n) / n
    ring = np.stack([np.cos(a), np.sin(a)], axis=1)
    vertices = np.concatenate([np.column_stack([ring * rad, np.full(n, z)]) for rad, z in profile])
    i = np.arange(n)
    j = (i + 1) % n
    faces = []
    for p in range(len(profile)):
        q = (p + 1) % len(profile)
        quad = (p * n + i, p * n + j, q * n + j, q * n + i)
        faces += [np.column_stack(quad[:3]), np.column_stack([quad[0], quad[2], quad[3]])]
    return vertices, np.concatenate(faces)
