"""End-effector orientation as yaw about base z applied to a fixed tool orientation.

The arms are driven with ``[x, y, z, yaw]``: the tool keeps a fixed orientation ``R0`` (e.g. pointing
down) and turns by ``yaw`` about the base z axis: ``R = Rz(yaw) @ R0``. These helpers convert to and
from the vendors' forms (xArm roll/pitch/yaw, UR rotation vector).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

# A measured tool orientation further than this from every Rz(yaw) R0 is a fault: the [x, y, z, yaw] commands
# cannot express it, so the first command would turn the wrist by all of it within one control period.
MAX_TILT_RAD = float(np.deg2rad(5.0))


def tool_rotation(yaw: float, r0: Rotation) -> Rotation:
    """``Rz(yaw) * R0``: the tool orientation at ``yaw`` (rad)."""
    return Rotation.from_euler("z", yaw) * r0


def yaw_of(r: Rotation, r0: Rotation) -> float:
    """Yaw (rad, [-pi, pi]) of a measured orientation ``r`` relative to the tool orientation ``r0``
    (the z-rotation closest to ``r * r0^-1``)."""
    m = (r * r0.inv()).as_matrix()
    return float(np.arctan2(m[1, 0], m[0, 0]))


def tilt_of(r: Rotation, r0: Rotation) -> float:
    """Angle (rad) between a measured orientation ``r`` and the tool orientation at its yaw, ``Rz(yaw_of) R0``."""
    return float((tool_rotation(yaw_of(r, r0), r0).inv() * r).magnitude())


def tilt_problem(r: Rotation, r0: Rotation, setting: str) -> str | None:
    """Why the measured orientation ``r`` is not one the commands can express (tilted more than MAX_TILT_RAD
    from ``r0``, the tool orientation ``setting`` configures), or None."""
    tilt = tilt_of(r, r0)
    if tilt <= MAX_TILT_RAD:
        return None
    return (f"the tool is tilted {np.rad2deg(tilt):.1f} deg from the orientation {setting} configures (at most "
            f"{np.rad2deg(MAX_TILT_RAD):.0f} deg): jog it there, or set {setting} to the tool's orientation at yaw 0")
