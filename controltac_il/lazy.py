"""Lazy package exports (PEP 562): a package's public names are imported from their modules on first use, so that
importing a package, and every CLI's ``--help``, costs no torch, diffusers, MuJoCo or OpenCV
(``tests/test_cli_imports.py``)."""

from __future__ import annotations

import importlib
import sys


def exports(package: str, table: dict[str, str]):
    """(``__getattr__``, ``__dir__``) for ``package``, whose public name ``n`` lives in the module ``table[n]``;
    each name is imported once, on first access, and kept in the package's namespace."""

    def __getattr__(name: str):
        if name not in table:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(table[name]), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(table) | set(vars(sys.modules[package])))

    return __getattr__, __dir__
