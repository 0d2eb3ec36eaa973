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
weights) + ``<stem>.json`` (step and the rest), written by :func:`save_run_state`. The learning-rate
schedule of every training is :func:`lr_schedule` (torch's schedulers), restored with the run state.

``python -m controltac_il.checkpoint sign FOLDER`` records the weights' hashes in a folder's model card
(for checkpoints written before the card carried them: check their contents first).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import warnings
from pathlib import Path
from typing import Callable, Mapping

import torch
from safetensors import SafetensorError
from safetensors.torch import load as load_safetensors
from safetensors.torch import load_file, save_file
from torch.optim.lr_scheduler import CosineAnnealingLR, LinearLR, LRScheduler, SequentialLR

from controltac_il.io import atomic_dir, atomic_path, write_json

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
                   meta: dict, optimizer: torch.optim.Optimizer | None = None, scheduler: LRScheduler | None = None,
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


def lr_schedule(optimizer: torch.optim.Optimizer, peaks: list[float], total: int, warmup: int,
                min_lr: float | None = None, resume: dict | None = None, step: int = 0) -> LRScheduler:
    """Linear warm-up over ``warmup`` steps (update i gets peak * (i + 1) / warmup), then a cosine decay to
    ``min_lr`` at update ``total`` (torch's LinearLR -> CosineAnnealingLR), or constant when ``min_lr`` is None.

    ``peaks``: each param group's peak LR (this run's settings). ``resume``: the ``lr_schedule`` entry of a
    saved run state; restored as it was when the settings match, else (e.g. more steps) this run's schedule
    continues from update ``step``. Call it after the optimizer state is loaded.
    """
    for g, peak in zip(optimizer.param_groups, peaks, strict=True):
        g["lr"] = g["initial_lr"] = peak
    warm = LinearLR(optimizer, 1 / warmup if warmup else 1.0, 1.0, total_iters=max(warmup - 1, 0))
    if min_lr is None:
        sched = warm
    else:
        cos = CosineAnnealingLR(optimizer, T_max=max(1, total - warmup), eta_min=min_lr)
        sched = SequentialLR(optimizer, [warm, cos], milestones=[warmup]) if warmup else cos
    sched.settings = {"peaks": list(peaks), "total": total, "warmup": warmup, "min_lr": min_lr}
    if resume is not None and resume.get("settings") == sched.settings:
        sched.load_state_dict(resume["state"])
        for g, lr in zip(optimizer.param_groups, sched.get_last_lr()):
            g["lr"] = lr
    else:
        with warnings.catch_warnings():  # stepping the schedule without optimizer steps, on purpose
            warnings.simplefilter("ignore", UserWarning)
            for _ in range(step):
                sched.step()
    return sched


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="python -m controltac_il.checkpoint",
                                description="Record the SHA-256 of a checkpoint folder's weights in its model card.")
    p.add_argument("command", choices=["sign"])
    p.add_argument("folders", nargs="+", type=Path)
    for folder in p.parse_args(argv).folders:
        print(folder, sign(folder)[HASH_KEY])


if __name__ == "__main__":
    main()
