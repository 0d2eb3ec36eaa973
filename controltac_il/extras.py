"""The optional parts of the install (pip extras) and the one-line error when one is missing.

A lab that only augments a LeRobot dataset installs the core; a robot, a gripper or the MuJoCo scene each need
their extra, as LeRobot's ``pip install lerobot[feetech]`` does: ``pip install 'controltac-il[ur]'`` and so on,
``[all]`` for everything (pyproject.toml lists them).
"""

from __future__ import annotations

import importlib
from types import ModuleType

# extra -> the distributions it installs (pyproject.toml's optional-dependencies must match: tested)
EXTRAS = {"ur": ("ur-rtde",), "xarm": ("xarm-python-sdk",), "dynamixel": ("dynamixel-sdk", "pyserial"),
          "robotiq": ("pyserial",), "sim": ("mujoco", "gymnasium")}


class MissingExtra(ImportError):
    """An optional dependency is not installed: the message names the extra that installs it."""


def require(module: str, extra: str, what: str) -> ModuleType:
    """``import module`` for ``what`` (e.g. "the UR arm"), or :class:`MissingExtra` naming ``extra``."""
    if extra not in EXTRAS:
        raise KeyError(f"unknown extra {extra!r} (known: {', '.join(EXTRAS)})")
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name is None or module.split(".")[0] != exc.name.split(".")[0]:
            raise  # a module of the package itself is broken: not a missing install
        dists = EXTRAS[extra]
        raise MissingExtra(f"{what} needs {' and '.join(dists)}, which {'are' if len(dists) > 1 else 'is'} not "
                           f"installed: pip install 'controltac-il[{extra}]'") from None
