"""Dimensions of the peg-in-hole scene, each with one owner, readable before any model is compiled.

Two kinds of owner (no number is written twice):

* the MJCF owns what it describes. These are read here from its text by element name, for what runs
  before a model exists (``envs.config``'s checks); code holding a compiled model reads the model
  instead (``PegInHoleEnv.peg_radius_m``, ``.peg_half_length_m``, ``.home_tcp``), and
  tests/test_env_scene.py checks that both readings agree:

      PEG_RADIUS_M, PEG_HALF_LENGTH_M   geom "peg"'s size (assets/peg_in_hole.xml)
      TABLE_HALF_SIZE_M                 geom "table"'s size (largest half side)
      PHYSICS_HZ                        1 / the option timestep
      HOME_TCP                          the "home" keyframe's hand joints (x, y, z m, yaw rad): where the hand starts

* this module owns the receptacle, which the MJCF leaves to Python so that the hole's size stays a
  parameter (``envs.scene.add_receptacle`` builds it from these): ``WALL_THICKNESS_M``,
  ``BASE_THICKNESS_M`` and ``rim_height_m``.

No MuJoCo import: the MJCF is read with the standard library's XML parser, its ``<include>``s expanded.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

ASSETS = Path(__file__).resolve().parent / "assets"
SCENE_XML = ASSETS / "peg_in_hole.xml"  # the scene; it includes the robot, GRIPPER_XML
GRIPPER_XML = ASSETS / "tactile_gripper.xml"
HAND_JOINTS = ("hand_x", "hand_y", "hand_z", "hand_yaw")  # the gripper's pose joints (and their servos' names)

WALL_THICKNESS_M = 0.012  # radial thickness of the receptacle's wall around the hole
BASE_THICKNESS_M = 0.008  # the plate under the hole (its top is the hole's floor)


def rim_height_m(hole_depth_mm: float) -> float:
    """Height of the hole's rim above the table (m)."""
    return BASE_THICKNESS_M + hole_depth_mm / 1000.0


def read_mjcf(path: Path = SCENE_XML) -> ET.Element:
    """The MJCF document at ``path`` with every ``<include file=...>`` replaced by the included file's
    elements (as MuJoCo's parser does)."""
    root = ET.parse(path).getroot()
    _expand_includes(root, path.parent)
    return root


def _expand_includes(element: ET.Element, folder: Path) -> None:
    for k, child in reversed(list(enumerate(element))):
        if child.tag == "include":
            included = read_mjcf(folder / child.get("file"))
            element.remove(child)
            for j, item in enumerate(included):
                element.insert(k + j, item)
        else:
            _expand_includes(child, folder)


def _default_classes(root: ET.Element) -> dict[str, tuple[ET.Element, str | None]]:
    """Default class name -> (its ``<default>`` element, parent class name); the top one is "main"."""
    classes: dict[str, tuple[ET.Element, str | None]] = {}

    def visit(element: ET.Element, parent: str | None) -> None:
        name = element.get("class", "main")
        classes[name] = (element, parent)
        for child in element.findall("default"):
            visit(child, name)

    for top in root.findall("default"):
        visit(top, None)
    return classes


def _qpos_width(joint: ET.Element, cls: str, classes: dict) -> int:
    """qpos entries of a joint: 7 free, 4 ball, 1 hinge or slide (its type set on it or by its class)."""
    if joint.tag == "freejoint":
        return 7
    kind, name = joint.get("type"), joint.get("class", cls)
    while kind is None and name in classes:
        element, name = classes[name]
        default = element.find("joint")
        kind = default.get("type") if default is not None else None
    return {"free": 7, "ball": 4}.get(kind, 1)


def qpos_addresses(root: ET.Element) -> dict[str, int]:
    """Joint name -> its first qpos index: bodies depth first in document order, each body's joints
    before its children's (MuJoCo's order)."""
    classes, addresses, at = _default_classes(root), {}, 0

    def visit(body: ET.Element, cls: str) -> None:
        nonlocal at
        cls = body.get("childclass", cls)
        for joint in body:
            if joint.tag in ("joint", "freejoint"):
                addresses[joint.get("name")] = at
                at += _qpos_width(joint, cls, classes)
        for child in body.findall("body"):
            visit(child, cls)

    for world in root.findall("worldbody"):
        visit(world, "main")
    return addresses


def _floats(text: str) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split())


def _named(root: ET.Element, tag: str, name: str) -> ET.Element:
    found = [e for e in root.iter(tag) if e.get("name") == name]
    if len(found) != 1:
        raise LookupError(f"the MJCF has {len(found)} <{tag} name={name!r}>, expected one")
    return found[0]


def _read_scene(path: Path = SCENE_XML) -> tuple[float, float, float, float, tuple[float, ...]]:
    """(peg radius, peg half length, table half size, physics rate, home TCP) as the MJCF at ``path`` has them."""
    root = read_mjcf(path)
    radius, half_length = _floats(_named(root, "geom", "peg").get("size"))[:2]
    table = max(_floats(_named(root, "geom", "table").get("size"))[:2])
    rate = 1.0 / float(root.find("option").get("timestep"))
    home, addresses = _floats(_named(root, "key", "home").get("qpos")), qpos_addresses(root)
    return radius, half_length, table, rate, tuple(home[addresses[name]] for name in HAND_JOINTS)


PEG_RADIUS_M, PEG_HALF_LENGTH_M, TABLE_HALF_SIZE_M, PHYSICS_HZ, HOME_TCP = _read_scene()
