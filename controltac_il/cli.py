"""What every command line of the project does with a fault it meets at run time: one line on stderr and an exit
code, never a traceback (1 a fault of the run itself, :class:`RunFault`; 2 bad input, data, file or folder; 130
Ctrl-C)."""

from __future__ import annotations

import argparse
import sys
from typing import Callable

from controltac_il.config import one_line
from controltac_il.extras import MissingExtra


def tty_only(progress: bool = True) -> bool | None:
    """tqdm's ``disable`` for a bar shown only on a terminal: None (tqdm turns it off when stderr is not a TTY, so
    ``./run.sh > log`` holds no carriage-return updates), or True when ``progress`` is off."""
    return None if progress else True


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser, but a usage error (unknown flag, bad choice, missing argument) is one line on stderr,
    ``PROG: error: MESSAGE (see --help)``, and exit status 2: the usage block is what ``--help`` is for."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


class RunFault(RuntimeError):
    """A fault of the run itself, not of its input (e.g. evaluation episodes that raised): one line, exit 1."""


def guard(prog: str, job: Callable[[], int | None], interrupted: str = "interrupted (Ctrl-C)") -> int:
    """Run ``job()`` and return its exit code (None = 0). A ValueError, OSError or a missing extra
    (:class:`MissingExtra`) becomes ``PROG: error: <one line>`` and 2; a :class:`RunFault` the same and 1; Ctrl-C
    its own message (e.g. where a run can be continued) or ``interrupted`` and 130."""
    try:
        return job() or 0
    except RunFault as exc:
        print(f"{prog}: error: {one_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as exc:
        print(f"{prog}: {str(exc) or interrupted}", file=sys.stderr)
        return 130
    except (ValueError, OSError, MissingExtra) as exc:
        print(f"{prog}: error: {one_line(exc)}", file=sys.stderr)
        return 2


def key_value_pairs(flag: str, values: list[str], form: str) -> dict[str, str]:
    """{key: value} of a flag's ``KEY=VALUE`` arguments (``form`` names them, e.g. TACTILE_KEY=PNG); ValueError
    "<flag>: expected <form> pairs, got ..." for another form, and naming a key given twice (no value silently
    replaces another)."""
    if not all("=" in x and all(x.split("=", 1)) for x in values):
        raise ValueError(f"{flag}: expected {form} pairs, got {' '.join(values)}")
    pairs = [x.split("=", 1) for x in values]
    keys = [k for k, _ in pairs]
    twice = next((k for k in keys if keys.count(k) > 1), None)
    if twice is not None:
        raise ValueError(f"{flag}: {twice!r} is given twice; give each key one value")
    return dict(pairs)
