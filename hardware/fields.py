"""Field types shared by the validated settings (pydantic v2): strict scalars, finite floats, fixed-length
vectors that YAML writes as lists, and one-line error messages with the field path.

Scalars are strict (no "5" -> 5, no true -> 1, no 2.5 -> int); an integer is accepted where a float is
expected, and numpy scalars and arrays as their Python values. Floats must be finite
(``allow_inf_nan=False`` in :data:`SETTINGS`).
"""

from __future__ import annotations

import ipaddress
import re
from typing import Annotated

import numpy as np
from pydantic import AfterValidator, BeforeValidator, ConfigDict, Field, Strict, ValidationError

SETTINGS = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)  # models (BaseModel)
DATACLASS_SETTINGS = ConfigDict(extra="forbid", allow_inf_nan=False)  # pydantic dataclasses (frozen=True on the decorator)

def _plain(v):
    return v.item() if isinstance(v, np.generic) else v


Float = Annotated[float, Strict(), BeforeValidator(_plain)]
Int = Annotated[int, Strict(), BeforeValidator(_plain)]
Str = Annotated[str, Strict()]
Bool = Annotated[bool, Strict()]


def _sequence(form: str):
    """Before-validator: a YAML list (or a tuple) of ``len(form.split(','))`` items becomes a tuple."""
    n = len(form.split(","))

    def check(v):
        if isinstance(v, (list, tuple, np.ndarray)):
            if len(v) != n:
                raise ValueError(f"expected {form} ({n} values), got {list(v)!r}")
            return tuple(v)
        return v

    return BeforeValidator(check)


Vec2 = Annotated[tuple[Float, Float], _sequence("[roll, pitch]")]
Vec3 = Annotated[tuple[Float, Float, Float], _sequence("[x, y, z]")]
PosInt = Annotated[Int, Field(ge=1)]
Pixels = Annotated[Int, Field(ge=1, le=4096)]
Size = Annotated[tuple[Pixels, Pixels], _sequence("[H, W]")]  # pixels


def _ip(v: str) -> str:
    """A literal IPv4 or IPv6 address a controller can have (not 0.0.0.0 / ::, multicast or broadcast)."""
    try:
        addr = ipaddress.ip_address(v)
    except ValueError:
        raise ValueError(f"expected an IP address such as 192.168.1.221, got {v!r}") from None
    if addr.is_unspecified or addr.is_multicast or addr == ipaddress.IPv4Address("255.255.255.255"):
        raise ValueError(f"{v} is not a controller's address (unspecified, multicast or broadcast); "
                         "expected the controller's own address such as 192.168.1.221")
    return v


IPAddress = Annotated[Str, AfterValidator(_ip)]


def _device(v):
    if isinstance(v, bool) or not isinstance(v, (str, int)):
        raise ValueError(f"expected a string (path or name) or an integer index, got {v!r}")
    return v


Device = Annotated[str | int, BeforeValidator(_device)]


def _path(loc) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def error_line(exc: ValidationError, source: str) -> str:
    """``<source>: <field path>: <problem>`` for every error of ``exc``, joined into one line.

    A validator message starting with ``<field>: `` (the field a cross-field check blames) extends the path;
    a validator that reports several problems joins them with ``"; "``, each starting with its ``<field>: ``.
    """
    parts = []
    for err in exc.errors(include_url=False):
        path, msg = _path(err["loc"]), err["msg"]
        kind = err["type"]
        if kind == "value_error":
            for problem in _PROBLEMS.split(msg.removeprefix("Value error, ")):
                head, sep, rest = problem.partition(": ")
                if sep and all(part.isidentifier() for part in head.split(".")):
                    parts.append(f"{f'{path}.{head}' if path else head}: {rest}")
                else:
                    parts.append(f"{path or 'setup'}: {problem}")
            continue
        if kind in ("extra_forbidden", "unexpected_keyword_argument"):
            msg = "unknown field"
        elif kind in ("missing", "missing_argument"):
            msg = "required field is missing"
        elif "input" in err and not isinstance(err["input"], dict):
            msg = f"{msg}, got {err['input']!r}"
        parts.append(f"{path or 'setup'}: {msg}")
    return f"{source}: " + "; ".join(parts)


_PROBLEMS = re.compile(r"; (?=[A-Za-z_][\w.]*: )")  # "; field: ..." starts the next problem of a validator
