"""End-effector orientation as yaw about base z applied to a fixed tool orientation.

The arms are driven with ``[x, y, z, yaw]``: the tool keeps a fixed orientation ``R0`` (e.g. pointing
down) and turns by ``yaw`` about the base z axis: ``R = Rz(yaw) @ R0``. These helpers convert to and
from the vendors' forms (xArm roll/pitch/yaw, UR rotation vector).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def tool_rotation(yaw: float, r0: Rotation) -> Rotation:
    """``Rz(yaw) * R0``: the tool orientation at ``yaw`` (rad)."""
    return Rotation.from_euler("z", yaw) * r0


def yaw_of(r: Rotation, r0: Rotation) -> float:
    """Yaw (rad, [-pi, pi]) of a measured orientation ``r`` relative to the tool orientation ``r0``
    (the z-rotation closest to ``r * r0^-1``)."""
    m = (r * r0.inv()).as_matrix()
    return float(np.arctan2(m[1, 0], m[0, 0]))
