"""One checkpoint convention for every model of the project, and the run states of their trainings.

A checkpoint is a folder, written atomically (it appears only when complete), nothing pickled::

    config.json            the model's config (``to_dict``)
    <name>.safetensors     weights (one file or several: the generator has two)
    model_card.json        provenance, and ``weights_sha256``: the SHA-256 of every .safetensors file
    ...                    other JSON files a model needs (ACT: stats.json)

``load_folder`` verifies before it builds anything: a missing file, a file whose hash differs from
the card's, a file safetensors cannot read, or NaN / inf in a float tensor raise :class:`CheckpointError`
(a ValueError; :class:`MissingCheckpointFile` is also a FileNotFoundError) naming the file.
``load_into`` then checks tensor names and shapes against the model built from the config.

Run states (resumable training) are ``<stem>.safetensors`` (module weights, optimizer tensors, EMA
weights) + ``<stem>.json`` (step, the rest, and the state of the run's LR schedule:
``controltac_il.training.lr_schedule``), written by :func:`save_run_state`.

:func:`claim_output` guards a run's output folder: it is only written where it holds nothing or this tool's own
output of a run being resumed (``--overwrite`` replaces only files the tool wrote). The other guards of a run
(NaN / inf loss, Ctrl-C) are in ``controltac_il.training``. :func:`one_line` turns a pydantic ValidationError
into one line naming the fields (or the CLI flags).

``python -m controltac_il.checkpoint sign FOLDER`` records the weights' hashes in a folder's model card
(for checkpoints written before the card carried them: check their contents first).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
from pathlib import Path
from typing import Callable, Mapping

import torch
from pydantic import TypeAdapter
from safetensors import SafetensorError
from safetensors.torch import load as load_safetensors
from safetensors.torch import load_file, save_file

from controltac_il.io import atomic_dir, atomic_path, write_json

CONFIG_FILE = "config.json"
CARD_FILE = "model_card.json"
HASH_KEY = "weights_sha256"


class CheckpointError(ValueError):
    """A checkpoint folder is missing, corrupted or does not fit the model built from its config."""


class MissingCheckpointFile(CheckpointError, FileNotFoundError):
    """A checkpoint folder or one of its files does not exist."""


class OutputInUse(ValueError):
    """An output folder holds files this run would replace: a previous run, or files of the user's."""


def one_line(exc: BaseException, flags: Mapping[str, str] | None = None) -> str:
    """One line for an error: a pydantic ValidationError becomes ``field: problem (got value)`` per error, the
    field spelled as its CLI flag where ``flags`` maps it (``{"steps": "--steps"}``); other errors their message
    with line breaks folded."""
    errors = getattr(exc, "errors", None)
    if callable(errors) and type(exc).__name__ == "ValidationError":
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
    return " ".join(str(exc).split()) or type(exc).__name__


def sha256_file(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def read_json(path: str | Path) -> dict:
    """A JSON object from ``path``; CheckpointError naming the file if it is missing or not valid JSON."""
    path = Path(path)
    if not path.is_file():
        raise MissingCheckpointFile(f"checkpoint file not found: {path}")
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise CheckpointError(f"checkpoint file is not valid JSON: {path}: {e}") from None
    if not isinstance(doc, dict):
        raise CheckpointError(f"{path}: expected a JSON object, got {type(doc).__name__}")
    return doc


class JsonConfig:
    """Mixin of the project's pydantic-dataclass configs: ``to_dict`` (JSON types, as ``config.json`` holds
    them) and ``from_dict`` (validated; unknown fields refused, so a config from another version is an error)."""

    def to_dict(self) -> dict:
        return TypeAdapter(type(self)).dump_python(self, mode="json")

    @classmethod
    def from_dict(cls, d: dict):
        return TypeAdapter(cls).validate_python(d)


def state_tensors(weights: torch.nn.Module | Mapping[str, torch.Tensor], dtype: torch.dtype | None = None
                  ) -> dict[str, torch.Tensor]:
    """A module's state dict (or a dict of tensors) on CPU, contiguous, floats cast to ``dtype`` if given."""
    state = weights.state_dict() if isinstance(weights, torch.nn.Module) else weights
    out = {}
    for k, v in state.items():
        v = v.detach().cpu()
        out[k] = (v.to(dtype) if dtype is not None and v.is_floating_point() else v).contiguous()
    return out


def sign(folder: str | Path, card: dict | None = None) -> dict:
    """Write ``model_card.json`` = ``card`` (default: the folder's current card, or {}) plus the SHA-256 of
    every .safetensors file in ``folder``; returns the card."""
    folder = Path(folder)
    if card is None:
        card = read_json(folder / CARD_FILE) if (folder / CARD_FILE).is_file() else {}
    hashes = {p.name: sha256_file(p) for p in sorted(folder.glob("*.safetensors"))}
    card = {**{k: v for k, v in card.items() if k != HASH_KEY}, HASH_KEY: hashes}
    write_json(folder / CARD_FILE, card)
    return card


def save_folder(path: str | Path, config: dict, weights: Mapping[str, torch.nn.Module | Mapping[str, torch.Tensor]],
                *, card: dict | None = None, dtype: torch.dtype | None = None,
                files: Mapping[str, object] | None = None, write_more: Callable[[Path], None] | None = None) -> Path:
    """Write a checkpoint folder atomically: ``config.json``, one safetensors file per ``weights`` entry
    (file name -> module or tensors; floats cast to ``dtype``), ``files`` (name -> text, or an object
    written as JSON), what ``write_more(folder)`` adds, and the model card."""
    path = Path(path)
    with atomic_dir(path) as tmp:
        write_json(tmp / CONFIG_FILE, config)
        for name, w in weights.items():
            save_file(state_tensors(w, dtype), str(tmp / name))
        for name, obj in (files or {}).items():
            (tmp / name).write_text(obj) if isinstance(obj, str) else write_json(tmp / name, obj)
        if write_more is not None:
            write_more(tmp)
        sign(tmp, card or {})
    return path


def load_folder(path: str | Path, weight_files: tuple[str, ...], optional: tuple[str, ...] = ()
                ) -> tuple[dict, dict[str, dict[str, torch.Tensor]]]:
    """(config dict, {file: tensors}) of a checkpoint folder, every weights file verified against the card.
    Files in ``optional`` are skipped when absent (but verified when present)."""
    path = Path(path)
    if not path.is_dir():
        raise MissingCheckpointFile(f"checkpoint folder not found: {path}")
    missing = [n for n in (CONFIG_FILE, CARD_FILE, *weight_files) if not (path / n).is_file()]
    if missing:
        hint = (f"; a folder written before checkpoints carried a model card can be signed after checking it: "
                f"python -m controltac_il.checkpoint sign {path}") if missing == [CARD_FILE] else ""
        raise MissingCheckpointFile(f"checkpoint files not found in {path}: {', '.join(missing)}{hint}")
    config = read_json(path / CONFIG_FILE)
    hashes = read_json(path / CARD_FILE).get(HASH_KEY)
    if not isinstance(hashes, dict):
        raise CheckpointError(f"{path / CARD_FILE} records no weights hashes ({HASH_KEY}); "
                              f"after checking the folder, run: python -m controltac_il.checkpoint sign {path}")
    out = {}
    for name in weight_files + optional:
        f = path / name
        if not f.is_file():
            if name in optional:
                continue
            raise MissingCheckpointFile(f"checkpoint file not found: {f}")
        if name not in hashes:
            raise CheckpointError(f"{f}: no hash for it in {path / CARD_FILE}")
        data = f.read_bytes()  # read once: hashed, then parsed
        if hashlib.sha256(data).hexdigest() != hashes[name]:
            raise CheckpointError(f"{f} is corrupted or was replaced: its SHA-256 differs from the one in {CARD_FILE}")
        try:
            tensors = load_safetensors(data)
        except (SafetensorError, OSError) as e:
            raise CheckpointError(f"{f} is corrupted or not a safetensors file: {e}") from None
        bad = [k for k, v in tensors.items() if v.is_floating_point() and not torch.isfinite(v).all()]
        if bad:
            raise CheckpointError(f"{f}: tensors {bad[:5]} contain NaN or inf")
        out[name] = tensors
    return config, out


def load_into(module: torch.nn.Module, state: Mapping[str, torch.Tensor], file: str | Path) -> None:
    """Load ``state`` into ``module`` (cast to its dtypes) after checking every name and shape."""
    expected = module.state_dict()
    missing, extra = sorted(set(expected) - set(state)), sorted(set(state) - set(expected))
    bad = sorted(k for k in set(expected) & set(state) if tuple(expected[k].shape) != tuple(state[k].shape))
    if missing or extra or bad:
        detail = [f"missing {missing[:5]}"] if missing else []
        detail += [f"unexpected {extra[:5]}"] if extra else []
        detail += ["shape mismatch " + ", ".join(f"{k}: file {tuple(state[k].shape)} vs config {tuple(expected[k].shape)}"
                                                 for k in bad[:5])] if bad else []
        raise CheckpointError(f"{file} does not match the model built from its {CONFIG_FILE} ({'; '.join(detail)})")
    module.load_state_dict({k: v.to(expected[k].dtype) for k, v in state.items()}, strict=True)


# -- run states ------------------------------------------------------------------------------------

def save_run_state(stem: str | Path, modules: Mapping[str, torch.nn.Module | Mapping[str, torch.Tensor]],
                   meta: dict, optimizer: torch.optim.Optimizer | None = None, scheduler: torch.optim.lr_scheduler.LRScheduler | None = None,
                   tensors: Mapping[str, torch.Tensor] | None = None) -> None:
    """Write ``<stem>.safetensors`` (``<name>.<key>`` per module, ``optimizer.<param>.<key>``, ``tensors``)
    and then ``<stem>.json`` (``meta``, the optimizer's groups and scalars, the LR schedule's state)."""
    stem = Path(stem)
    out = {f"{name}.{k}": v for name, m in modules.items() for k, v in state_tensors(m).items()}
    doc = dict(meta)
    if optimizer is not None:
        sd = optimizer.state_dict()
        scalars = {}
        for pid, st in sd["state"].items():
            for k, v in st.items():
                if torch.is_tensor(v):
                    out[f"optimizer.{pid}.{k}"] = v.detach().cpu().contiguous()
                else:
                    scalars[f"{pid}.{k}"] = v
        doc.update(param_groups=sd["param_groups"], optimizer_scalars=scalars)
    if scheduler is not None:
        doc["lr_schedule"] = {"settings": scheduler.settings, "state": scheduler.state_dict()}
    out.update({k: v.detach().cpu().contiguous() for k, v in (tensors or {}).items()})
    with atomic_path(stem.with_suffix(".safetensors")) as tmp:
        save_file(out, str(tmp))
    write_json(stem.with_suffix(".json"), doc)


def load_run_state(stem: str | Path, modules: Mapping[str, torch.nn.Module],
                   optimizer: torch.optim.Optimizer | None = None) -> tuple[dict, dict[str, torch.Tensor]]:
    """Restore what :func:`save_run_state` wrote into ``modules`` and ``optimizer``; returns (meta, all tensors)."""
    stem = Path(stem)
    meta = read_json(stem.with_suffix(".json"))
    try:
        tensors = load_file(str(stem.with_suffix(".safetensors")))
    except (SafetensorError, OSError) as e:
        raise CheckpointError(f"{stem.with_suffix('.safetensors')}: cannot read the training state: {e}") from None
    for name, m in modules.items():
        n = len(name) + 1
        load_into(m, {k[n:]: v for k, v in tensors.items() if k.startswith(name + ".")}, stem.with_suffix(".safetensors"))
    if optimizer is not None:
        state: dict[int, dict] = {}
        items = [(k[len("optimizer."):], v) for k, v in tensors.items() if k.startswith("optimizer.")]
        if not items and "optimizer_scalars" not in meta:  # another layout: resuming would silently reset AdamW
            raise CheckpointError(f"{stem}: no optimizer state in the layout this version reads (written by an older "
                                  "version?); start a new run")
        for key, v in items + list(meta.get("optimizer_scalars", {}).items()):
            pid, name = key.split(".", 1)
            state.setdefault(int(pid), {})[name] = v
        try:
            optimizer.load_state_dict({"state": state, "param_groups": meta["param_groups"]})
        except (KeyError, ValueError) as e:
            raise CheckpointError(f"{stem}: the optimizer state does not fit this model: {e}") from None
    return meta, tensors


# -- guards of a training run ---------------------------------------------------------------------

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


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="python -m controltac_il.checkpoint",
                                description="Record the SHA-256 of a checkpoint folder's weights in its model card.")
    p.add_argument("command", choices=["sign"])
    p.add_argument("folders", nargs="+", type=Path)
    for folder in p.parse_args(argv).folders:
        print(folder, sign(folder)[HASH_KEY])


if __name__ == "__main__":
    main()
