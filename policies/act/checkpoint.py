"""ACT checkpoints: the project's checkpoint convention (``controltac_il.checkpoint``), nothing pickled.

    config.json                     {"format", "version", "act": ACTConfig fields, "meta": {...}}
    model.safetensors               network weights
    stats.json                      normalisation statistics (qpos and action mean/std)
    tactile_background.safetensors  one uint8 (H, W, 3) no-contact frame per tactile sensor (optional)
    optimizer.safetensors + optimizer.json   AdamW + LR-schedule state for ``--resume`` (optional)
    model_card.json                 the SHA-256 of every .safetensors file, verified at load

Loading validates every file and raises :class:`CheckpointError` (a ValueError) with the file
and the problem, so a bad checkpoint is refused before a robot moves.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from controltac_il.checkpoint import (CONFIG_FILE, CheckpointError, MissingCheckpointFile, load_folder, load_into,
                                      read_json, save_folder)
from controltac_il.config import one_line
from controltac_il.run_state import load_run_state, save_run_state
from controltac_il.training import parse_device
from policies.act.configuration_act import ACTConfig
from policies.act.modeling_act import ACT

FORMAT = "controltac-il/act"
VERSION = 1
WEIGHTS_FILE = "model.safetensors"
BACKGROUND_FILE = "tactile_background.safetensors"
__all__ = ["CheckpointError", "load_checkpoint", "load_optimizer_state", "read_config", "save_checkpoint"]


def save_checkpoint(out_dir: str | Path, model: ACT, *, backgrounds: dict[str, np.ndarray] | None = None,
                    meta: dict | None = None, optimizer: torch.optim.Optimizer | None = None, scheduler=None) -> Path:
    """Write ``model`` (+ its stats, tactile backgrounds, optimizer and LR-schedule state) to ``out_dir`` atomically."""
    weights = {WEIGHTS_FILE: model}
    if backgrounds:
        weights[BACKGROUND_FILE] = {k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.uint8)) for k, v in backgrounds.items()}
    config = {"format": FORMAT, "version": VERSION, "act": model.config.to_dict(), "meta": meta or {}}
    return save_folder(out_dir, config, weights, card={"model": "controltac-il ACT policy"},
                       files={"stats.json": model.get_stats()},
                       write_more=None if optimizer is None else
                       lambda tmp: save_run_state(tmp / "optimizer", {}, {}, optimizer, scheduler))


def load_optimizer_state(ckpt_dir: str | Path, optimizer: torch.optim.Optimizer) -> dict | None:
    """Restore the AdamW state saved with :func:`save_checkpoint` into ``optimizer``; returns the saved
    LR-schedule state (None if none was saved)."""
    ckpt_dir = Path(ckpt_dir)
    if not (ckpt_dir / "optimizer.json").is_file():
        raise CheckpointError(f"{ckpt_dir}: no optimizer state (optimizer.json) for --resume")
    meta, _ = load_run_state(ckpt_dir / "optimizer", {}, optimizer)
    return meta.get("lr_schedule")


def read_config(ckpt_dir: str | Path) -> tuple[ACTConfig, dict]:
    """The checkpoint's :class:`ACTConfig` and its ``meta`` dict, validated."""
    ckpt_dir = Path(ckpt_dir)
    if not ckpt_dir.is_dir():
        raise MissingCheckpointFile(f"checkpoint folder not found: {ckpt_dir}")
    doc = read_json(ckpt_dir / CONFIG_FILE)
    if doc.get("format") != FORMAT:
        raise CheckpointError(f"{ckpt_dir / CONFIG_FILE}: format is {doc.get('format')!r}, expected {FORMAT!r}")
    if doc.get("version") != VERSION:
        raise CheckpointError(f"{ckpt_dir / CONFIG_FILE}: version {doc.get('version')!r}, expected {VERSION}")
    try:
        config = ACTConfig.from_dict(doc.get("act"))
    except ValueError as e:
        raise CheckpointError(f"{ckpt_dir / CONFIG_FILE}: invalid ACT config: {one_line(e)}") from None
    return config, doc.get("meta") or {}


def load_checkpoint(ckpt_dir: str | Path, device: str | torch.device = "cpu"
                    ) -> tuple[ACT, dict[str, np.ndarray], dict]:
    """Load (model in eval mode, tactile backgrounds by sensor, meta) from a checkpoint folder; ValueError naming
    ``device`` for one this machine does not have."""
    device = parse_device(device)
    ckpt_dir = Path(ckpt_dir)
    config, meta = read_config(ckpt_dir)
    _, files = load_folder(ckpt_dir, (WEIGHTS_FILE,), optional=(BACKGROUND_FILE,))
    model = ACT(config)
    load_into(model, files[WEIGHTS_FILE], ckpt_dir / WEIGHTS_FILE)
    try:
        model.set_stats(read_json(ckpt_dir / "stats.json"))
    except CheckpointError:
        raise
    except ValueError as e:
        raise CheckpointError(f"{ckpt_dir / 'stats.json'}: {one_line(e)}") from None
    backgrounds = {k: v.numpy() for k, v in files.get(BACKGROUND_FILE, {}).items()}
    return model.to(device).eval(), backgrounds, meta
