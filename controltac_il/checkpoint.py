"""One checkpoint convention for every model of the project.

A checkpoint is a folder, written atomically (it appears only when complete), nothing pickled::

    config.json            the model's config (``to_dict``)
    <name>.safetensors     weights (one file or several: the generator has two)
    model_card.json        provenance, and ``weights_sha256``: the SHA-256 of every .safetensors file
    ...                    other JSON files a model needs (ACT: stats.json)

``load_folder`` verifies before it builds anything: a missing file, a file whose hash differs from
the card's, a file safetensors cannot read, or NaN / inf in a float tensor raise :class:`CheckpointError`
(a ValueError; :class:`MissingCheckpointFile` is also a FileNotFoundError) naming the file.
``load_into`` then checks tensor names and shapes against the model built from the config.

Beside it, one job each: run states of resumable trainings (``controltac_il.run_state``), the guard of a run's
output folder (``controltac_il.outputs``), the configs' base and their one-line errors (``controltac_il.config``),
and ``python -m controltac_il.sign FOLDER`` (record the weights' hashes in an older folder's model card).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Mapping

from controltac_il.io import atomic_dir, write_json

if TYPE_CHECKING:  # torch and safetensors are imported where tensors are (de)serialised: the CLIs' --help stays light
    import torch

CONFIG_FILE = "config.json"
CARD_FILE = "model_card.json"
HASH_KEY = "weights_sha256"


class CheckpointError(ValueError):
    """A checkpoint folder is missing, corrupted or does not fit the model built from its config."""


class MissingCheckpointFile(CheckpointError, FileNotFoundError):
    """A checkpoint folder or one of its files does not exist."""


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


def state_tensors(weights: torch.nn.Module | Mapping[str, torch.Tensor], dtype: torch.dtype | None = None
                  ) -> dict[str, torch.Tensor]:
    """A module's state dict (or a dict of tensors) on CPU, contiguous, floats cast to ``dtype`` if given."""
    import torch

    state = weights.state_dict() if isinstance(weights, torch.nn.Module) else weights
    out = {}
    for k, v in state.items():
        v = v.detach().cpu()
        out[k] = (v.to(dtype) if dtype is not None and v.is_floating_point() else v).contiguous()
    return out


def non_finite(tensors: Mapping[str, torch.Tensor]) -> list[str]:
    """The names of the floating-point tensors holding NaN or inf."""
    import torch

    return [k for k, v in tensors.items() if v.is_floating_point() and not torch.isfinite(v).all()]


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
    written as JSON), what ``write_more(folder)`` adds, and the model card. ``path`` may exist only as an empty
    folder or a checkpoint whose every file the new one rewrites; anything else is refused (ValueError), untouched."""
    from safetensors.torch import save_file

    path = Path(path)
    _check_replaceable(path)
    with atomic_dir(path) as tmp:
        write_json(tmp / CONFIG_FILE, config)
        for name, w in weights.items():
            tensors = state_tensors(w, dtype)
            bad = non_finite(tensors)
            if bad:  # what load_folder would refuse: never written (a NaN update, or beyond the range of dtype)
                raise CheckpointError(f"{path}: not saved: {name} tensors {bad[:5]} hold NaN or inf"
                                      + (f" as {str(dtype).removeprefix('torch.')}" if dtype is not None else ""))
            save_file(tensors, str(tmp / name))
        for name, obj in (files or {}).items():
            (tmp / name).write_text(obj) if isinstance(obj, str) else write_json(tmp / name, obj)
        if write_more is not None:
            write_more(tmp)
        sign(tmp, card or {})
        _check_replaceable(path, tmp)
    return path


def _check_replaceable(path: Path, new: Path | None = None) -> None:
    """ValueError unless ``path`` is absent, an empty folder, or a checkpoint (config.json, a model card with the
    weights' hashes) holding no file the ``new`` checkpoint folder lacks but its own human-readable card
    (README.md, written only where a card is given): a file or folder of the user's is never replaced."""
    if not path.exists() and not path.is_symlink():
        return
    if not path.is_dir() or path.is_symlink():
        raise ValueError(f"{path}: exists and is not a folder; a checkpoint is a folder: pass a new path")
    names = sorted(p.name for p in path.iterdir())
    if not names:
        return
    try:
        card = read_json(path / CARD_FILE) if (path / CONFIG_FILE).is_file() else {}
    except CheckpointError:  # missing or not JSON: not a checkpoint of ours
        card = {}
    if HASH_KEY not in card:
        raise ValueError(f"{path}: exists and is not a checkpoint folder (no {CONFIG_FILE} and model card with the "
                         "weights' hashes); refusing to replace it: pass a new path or an empty folder")
    extra = [n for n in names if new is not None and not (new / n).exists() and n != "README.md"]
    if extra:
        raise ValueError(f"{path}: holds {extra[:3]}, which this checkpoint does not write; refusing to replace it "
                         "(move them out, or pass a new path)")


def load_folder(path: str | Path, weight_files: tuple[str, ...], optional: tuple[str, ...] = ()
                ) -> tuple[dict, dict[str, dict[str, torch.Tensor]]]:
    """(config dict, {file: tensors}) of a checkpoint folder, every weights file verified against the card.
    Files in ``optional`` are skipped when absent (but verified when present)."""
    from safetensors import SafetensorError
    from safetensors.torch import load as load_safetensors

    path = Path(path)
    if not path.is_dir():
        raise MissingCheckpointFile(f"checkpoint folder not found: {path}")
    missing = [n for n in (CONFIG_FILE, CARD_FILE, *weight_files) if not (path / n).is_file()]
    if missing:
        hint = (f"; a folder written before checkpoints carried a model card can be signed after checking it: "
                f"python -m controltac_il.sign {path}") if missing == [CARD_FILE] else ""
        raise MissingCheckpointFile(f"checkpoint files not found in {path}: {', '.join(missing)}{hint}")
    config = read_json(path / CONFIG_FILE)
    hashes = read_json(path / CARD_FILE).get(HASH_KEY)
    if not isinstance(hashes, dict):
        raise CheckpointError(f"{path / CARD_FILE} records no weights hashes ({HASH_KEY}); "
                              f"after checking the folder, run: python -m controltac_il.sign {path}")
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
        bad = non_finite(tensors)
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
