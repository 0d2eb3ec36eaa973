"""The guard of a run's output folder: it is only written where it holds nothing or this tool's own output of a
run being resumed (``--overwrite`` replaces only files the tool wrote; files of the user's are never touched).
The other guards of a run (NaN / inf loss, Ctrl-C) are in ``controltac_il.training``."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Callable, Mapping

from controltac_il.checkpoint import CARD_FILE, CONFIG_FILE, HASH_KEY


class OutputInUse(ValueError):
    """An output folder holds files this run would replace: a previous run, or files of the user's."""


def own_json(*keys: str) -> Callable[[Path], str | None]:
    """Recogniser of a JSON file this tool wrote: a JSON object holding every one of ``keys``."""
    def check(path: Path) -> str | None:
        if not path.is_file():
            return "not a file"
        try:
            doc = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            return "not JSON"
        missing = [k for k in keys if not isinstance(doc, dict) or k not in doc]
        return f"it lacks {missing}" if missing else None
    return check


def own_safetensors(*prefixes: str) -> Callable[[Path], str | None]:
    """Recogniser of a safetensors file this tool wrote: readable, every tensor name starting with one of
    ``prefixes``."""
    def check(path: Path) -> str | None:
        from safetensors import safe_open

        if not path.is_file():
            return "not a file"
        try:
            with safe_open(str(path), "pt") as f:
                names = list(f.keys())
        except Exception:  # noqa: BLE001 - any unreadable file is not ours
            return "not a safetensors file"
        odd = [n for n in names if not n.startswith(prefixes)]
        return f"it holds tensors {odd[:3]}" if odd else None
    return check


def own_checkpoint(files: tuple[str, ...], config_check: Callable[[dict], bool] | None = None
                   ) -> Callable[[Path], str | None]:
    """Recogniser of a checkpoint folder this tool wrote: only the names in ``files``, among them config.json and
    a model card recording the weights' hashes, and a config ``config_check`` accepts."""
    def check(path: Path) -> str | None:
        if not path.is_dir():
            return "not a folder"
        foreign = sorted(p.name for p in path.iterdir() if p.name not in files or not p.is_file())
        if foreign:
            return f"{path / foreign[0]} is not a file this tool writes"
        for name in (CONFIG_FILE, CARD_FILE):
            if not (path / name).is_file():
                return f"it has no {name}"
        try:
            config, card = json.loads((path / CONFIG_FILE).read_text()), json.loads((path / CARD_FILE).read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            return "its config.json or model card is not JSON"
        if not isinstance(card, dict) or HASH_KEY not in card:
            return "its model card records no weights hashes"
        if config_check is not None and not (isinstance(config, dict) and config_check(config)):
            return "its config.json is not this model's"
        return None
    return check


def claim_output(out: str | Path, outputs: Mapping[str, Callable[[Path], str | None]], *, resume: bool = False,
                 overwrite: bool = False, tool: str = "this tool", label: str | None = None) -> list[str]:
    """Make sure a training may write ``outputs`` (names under ``out``, each with a recogniser returning None for
    this tool's own output, else why not) without destroying anything of the user's.

    Anything present that the tool did not write is refused, always (it would be replaced during training).
    Without ``resume`` or ``overwrite``, a previous run's output is refused, naming the flags; with ``overwrite``
    it is removed (only the entries recognised, nothing else under ``out``). Returns the names present.
    Raises :class:`OutputInUse` (a ValueError) naming the folder or the file.
    """
    out = Path(out)
    label = label or str(out)
    if out.exists() and not out.is_dir():
        raise OutputInUse(f"--out {label} is a file, not a folder")
    blocking = next((p for p in out.parents if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise OutputInUse(f"--out {label}: {blocking} is a file, so no folder can be made under it")
    present = [n for n in outputs if (out / n).exists() or (out / n).is_symlink()]
    for name in present:
        why = "a link" if (out / name).is_symlink() else outputs[name](out / name)
        if why:
            raise OutputInUse(f"{out / name} was not written by {tool} ({why}); nothing was changed: "
                              f"choose another --out (it is never deleted, not even with --overwrite)")
    if present and not resume:
        if not overwrite:
            raise OutputInUse(f"--out {label} already holds a previous run ({', '.join(present)}): pass --resume "
                              "to continue it, --overwrite to replace it (only files this tool wrote), or choose "
                              "another --out")
        for name in present:
            shutil.rmtree(out / name) if (out / name).is_dir() else (out / name).unlink()
    return present
