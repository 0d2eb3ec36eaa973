"""The one config idiom of the project and its errors.

Every config is a pydantic dataclass with ``config=STRICT`` (fields validated at construction, unknown fields
refused; ``one_line_errors`` makes its constructor raise one line); model configs also inherit :class:`JsonConfig` (``to_dict`` / ``from_dict``, as ``config.json`` holds
them). :func:`one_line` turns any error, a pydantic ValidationError included, into the one line a CLI prints,
naming the fields (or their CLI flags).
"""

from __future__ import annotations

import functools
import math
import numbers
from argparse import ArgumentTypeError
from typing import Annotated, Mapping

import numpy as np
from pydantic import ConfigDict, Field, TypeAdapter, ValidationError

STRICT = ConfigDict(extra="forbid")
AUTO = "auto"  # a batch size the generator picks for its device (generator.batching)
PosInt = Annotated[int, Field(gt=0)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]  # finite and > 0


def is_int(value) -> bool:
    """An int or a numpy integer, never a bool (True is an int to Python, not a count or an index to a user)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def is_real(value) -> bool:
    """A finite real number, numpy's included, never a bool, a string, None or a complex number."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def parse_batch_size(text: str):
    """A --batch-size value: "auto" or an int >= 1 (argparse's ``type``)."""
    if text == AUTO:
        return AUTO
    if not text.isdigit() or int(text) < 1:
        raise ArgumentTypeError(f"expected an int >= 1 or 'auto', got {text!r}")
    return int(text)


class JsonConfig:
    """Mixin of the project's pydantic-dataclass configs: ``to_dict`` (JSON types, as ``config.json`` holds
    them) and ``from_dict`` (validated; unknown fields refused, so a config from another version is an error;
    :class:`FieldErrors`, one line)."""

    def to_dict(self) -> dict:
        return TypeAdapter(type(self)).dump_python(self, mode="json")

    @classmethod
    def from_dict(cls, d: dict):
        try:
            return TypeAdapter(cls).validate_python(d)
        except ValidationError as exc:
            raise FieldErrors.of(exc) from None


def one_line(exc: BaseException, flags: Mapping[str, str] | None = None) -> str:
    """One line for an error: a pydantic ValidationError becomes ``field: problem (got value)`` per error, the
    field spelled as its CLI flag where ``flags`` maps it (``{"steps": "--steps"}``); other errors their message
    with line breaks folded, and their notes after it (e.g. a device that failed to stop after the fault)."""
    errors = getattr(exc, "errors", None)
    if callable(errors) and (type(exc).__name__ == "ValidationError" or isinstance(exc, FieldErrors)):
        grouped: dict[tuple[str, str], tuple[list[str], str]] = {}
        for err in exc.errors():
            loc = [str(x) for x in err.get("loc", ())]
            items = []
            while len(loc) > 1 and loc[-1].isdigit():  # latent_scale.0 .. latent_scale.7 -> one entry
                items.insert(0, loc.pop())
            if loc and flags and loc[0] in flags:
                name = ".".join([flags[loc[0]], *loc[1:]])
            else:
                name = ".".join(loc) or exc.title
            msg = err.get("msg", "invalid").removeprefix("Value error, ")
            plain = err.get("loc") and err.get("type") != "missing" and not isinstance(err.get("input"), dict)
            shown = f" (got {err.get('input')!r})" if plain else ""
            entry = grouped.setdefault((name, msg), ([], shown))
            entry[0].extend(items)
        parts = [f"{name}{'[' + ', '.join(items) + ']' if items else ''}: {msg}{shown}"
                 for (name, msg), (items, shown) in grouped.items()]
        return "; ".join(parts)
    return "; ".join(" ".join(str(part).split()) for part in [str(exc) or type(exc).__name__,
                                                             *getattr(exc, "__notes__", ())])


def add_note(exc: BaseException, note: str) -> None:
    """``exc.add_note(note)``, also on Python 3.10 (which has no add_note but keeps ``__notes__``): what else went
    wrong while ``exc`` propagated, printed after its message by :func:`one_line`."""
    if hasattr(exc, "add_note"):
        exc.add_note(note)
    else:
        exc.__notes__ = [*getattr(exc, "__notes__", ()), note]


class FieldErrors(ValueError):
    """A pydantic ValidationError as a ValueError of one line naming the field(s) (``one_line``); ``errors()`` and
    ``title`` kept, so that a command can still name its flags (``one_line(exc, flags)``). Picklable: a config
    refused in a worker process reaches the parent as this line."""

    def __init__(self, message: str, errors: list, title: str):
        super().__init__(message)
        self._errors, self.title = errors, title

    @classmethod
    def of(cls, exc: ValidationError) -> "FieldErrors":
        return cls(one_line(exc), exc.errors(include_url=False), exc.title)

    def errors(self) -> list:
        return self._errors

    def __reduce__(self):
        return type(self), (str(self), self._errors, self.title)


def one_line_errors(cls):
    """Class decorator for a pydantic dataclass: its constructor (``dataclasses.replace`` included) raises
    :class:`FieldErrors` instead of the multi-line ValidationError."""
    validate = cls.__init__

    @functools.wraps(validate)
    def __init__(self, *args, **kwargs):
        try:
            validate(self, *args, **kwargs)
        except ValidationError as exc:
            raise FieldErrors.of(exc) from None

    cls.__init__ = __init__
    return cls
