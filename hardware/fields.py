"""Field types shared by the validated settings (pydantic dataclasses with ``config=STRICT``, the project's one
config idiom, :mod:`controltac_il.config`): strict scalars, finite floats, fixed-length vectors that YAML writes
as lists, and :class:`Problems`, which raises the findings of a cross-field check at their fields' paths.

Scalars are strict (no "5" -> 5, no true -> 1, no 2.5 -> int); an integer is accepted where a float is
expected, and numpy scalars and arrays as their Python values. Floats must be finite (``AllowInfNan(False)``
in :data:`Float`). Every error is formatted by the project's one formatter, :func:`controltac_il.config.one_line`
(``field.path: problem (got value)``).
"""

from __future__ import annotations

import ipaddress
from typing import Annotated, Any

import numpy as np
from pydantic import AfterValidator, BeforeValidator, Field, Strict, ValidationError
from pydantic.types import AllowInfNan
from pydantic_core import InitErrorDetails, PydanticCustomError


def _plain(v):
    return v.item() if isinstance(v, np.generic) else v


Float = Annotated[float, Strict(), AllowInfNan(False), BeforeValidator(_plain)]
Int = Annotated[int, Strict(), BeforeValidator(_plain)]
Str = Annotated[str, Strict()]
Bool = Annotated[bool, Strict()]


def _sequence(form: str):
    """Before-validator: a YAML list (or a tuple) of ``len(form.split(','))`` items becomes a tuple."""
    n = len(form.split(","))

    def check(v):
        if isinstance(v, (list, tuple, np.ndarray)):
            if len(v) != n:
                raise ValueError(f"expected {form} ({n} values)")
            return tuple(v)
        return v

    return BeforeValidator(check)


Vec2 = Annotated[tuple[Float, Float], _sequence("[roll, pitch]")]
Vec3 = Annotated[tuple[Float, Float, Float], _sequence("[x, y, z]")]
Pixels = Annotated[Int, Field(ge=1, le=4096)]
Size = Annotated[tuple[Pixels, Pixels], _sequence("[H, W]")]  # pixels


def _ip(v: str) -> str:
    """A literal IPv4 or IPv6 address a controller can have (not 0.0.0.0 / ::, multicast or broadcast)."""
    try:
        addr = ipaddress.ip_address(v)
    except ValueError:
        raise ValueError("expected an IP address such as 192.168.1.221") from None
    if addr.is_unspecified or addr.is_multicast or addr == ipaddress.IPv4Address("255.255.255.255"):
        raise ValueError("not a controller's address (unspecified, multicast or broadcast); expected the "
                         "controller's own address such as 192.168.1.221")
    return v


IPAddress = Annotated[Str, AfterValidator(_ip)]


def _device(v):
    if isinstance(v, bool) or not isinstance(v, (str, int)):
        raise ValueError("expected a string (path or name) or an integer index")
    return v


Device = Annotated[str | int, BeforeValidator(_device)]


class Problems:
    """What a cross-field check found, each problem at its own field's path (``"limits.max_step_m"``,
    relative to the model that checks); :meth:`raise_any` raises them together as one pydantic
    ValidationError, so a section's problems get the section's path in front and
    :func:`~controltac_il.config.one_line` prints every one as ``path: problem (got value)``."""

    def __init__(self, title: str):
        self.title, self.errors = title, []

    def add(self, path: str, message: str, value: Any) -> None:
        """``path`` has a problem with its ``value`` (printed after the message)."""
        self.errors.append(InitErrorDetails(type=PydanticCustomError("value_error", message),
                                            loc=tuple(path.split(".")), input=value))

    def missing(self, path: str, message: str) -> None:
        """``path`` is required here and was not given."""
        self.errors.append(InitErrorDetails(type=PydanticCustomError("missing", message),
                                            loc=tuple(path.split(".")) if path else (), input=None))

    def raise_any(self) -> None:
        if self.errors:
            raise ValidationError.from_exception_data(self.title, self.errors)
