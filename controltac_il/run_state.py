"""Run states of resumable trainings: ``<stem>.safetensors`` (module weights, optimizer tensors, EMA weights,
other tensors) + ``<stem>.json`` (step, the rest, and the state of the run's LR schedule:
``controltac_il.training.lr_schedule``). Nothing pickled; the JSON is written last, so a state is complete
when its JSON exists."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from controltac_il.checkpoint import (
    CheckpointError,
    load_into,
    read_json,
    state_tensors,
)
from controltac_il.io import atomic_path, write_json


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
