"""ACT checkpoints: a folder written atomically, nothing pickled.

    config.json                     {"format", "version", "act": ACTConfig fields, "meta": {...}}
    model.safetensors               network weights
    stats.json                      normalisation statistics (qpos and action mean/std)
    tactile_background.safetensors  one uint8 (H, W, 3) no-contact frame per tactile sensor (optional)
    optimizer.safetensors + optimizer.json   AdamW state for ``--resume`` (optional)

Loading validates every file and raises :class:`CheckpointError` (a ValueError) with the file
and the problem, so a bad checkpoint is refused before a robot moves.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from controltac_il.io import atomic_dir
from policies.act.configuration_act import ACTConfig
from policies.act.modeling_act import ACT

FORMAT = "controltac-il/act"
VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint folder is missing, corrupted or does not fit the model / data."""


def save_checkpoint(out_dir: str | Path, model: ACT, *, backgrounds: dict[str, np.ndarray] | None = None,
                    meta: dict | None = None, optimizer: torch.optim.Optimizer | None = None) -> Path:
    """Write ``model`` (+ its stats, tactile backgrounds, optimizer state) to ``out_dir`` atomically."""
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        (tmp / "config.json").write_text(json.dumps(
            {"format": FORMAT, "version": VERSION, "act": model.config.to_dict(), "meta": meta or {}}, indent=2))
        state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
        save_file(state, str(tmp / "model.safetensors"))
        (tmp / "stats.json").write_text(json.dumps(model.get_stats(), indent=2))
        if backgrounds:
            save_file({k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.uint8)) for k, v in backgrounds.items()},
                      str(tmp / "tactile_background.safetensors"))
        if optimizer is not None:
            _save_optimizer(tmp, optimizer)
    return out_dir


def _save_optimizer(folder: Path, optimizer: torch.optim.Optimizer) -> None:
    sd = optimizer.state_dict()
    tensors, scalars = {}, {}
    for idx, st in sd["state"].items():
        for name, value in st.items():
            if torch.is_tensor(value):
                tensors[f"{idx}.{name}"] = value.detach().cpu().contiguous()
            else:
                scalars[f"{idx}.{name}"] = value
    save_file(tensors, str(folder / "optimizer.safetensors"))
    (folder / "optimizer.json").write_text(json.dumps({"param_groups": sd["param_groups"], "scalars": scalars}))


def load_optimizer_state(ckpt_dir: str | Path, optimizer: torch.optim.Optimizer) -> None:
    """Restore the AdamW state saved with :func:`save_checkpoint` into ``optimizer``."""
    ckpt_dir = Path(ckpt_dir)
    try:
        tensors = load_file(str(ckpt_dir / "optimizer.safetensors"))
        doc = json.loads((ckpt_dir / "optimizer.json").read_text())
    except (OSError, SafetensorError, json.JSONDecodeError) as e:
        raise CheckpointError(f"{ckpt_dir}: cannot read the optimizer state for --resume: {e}") from None
    state: dict[int, dict] = {}
    for key, value in list(tensors.items()) + list(doc.get("scalars", {}).items()):
        idx, name = key.split(".", 1)
        state.setdefault(int(idx), {})[name] = value
    try:
        optimizer.load_state_dict({"state": state, "param_groups": doc["param_groups"]})
    except (KeyError, ValueError) as e:
        raise CheckpointError(f"{ckpt_dir}: optimizer state does not fit this model: {e}") from None


def _read_json(path: Path) -> dict:
    if not path.is_file():
        raise CheckpointError(f"checkpoint file missing: {path}")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise CheckpointError(f"checkpoint file is not valid JSON: {path}: {e}") from None


def read_config(ckpt_dir: str | Path) -> tuple[ACTConfig, dict]:
    """The checkpoint's :class:`ACTConfig` and its ``meta`` dict, validated."""
    ckpt_dir = Path(ckpt_dir)
    if not ckpt_dir.is_dir():
        raise CheckpointError(f"checkpoint folder not found: {ckpt_dir}")
    doc = _read_json(ckpt_dir / "config.json")
    if doc.get("format") != FORMAT:
        raise CheckpointError(f"{ckpt_dir / 'config.json'}: format is {doc.get('format')!r}, expected {FORMAT!r}")
    if doc.get("version") != VERSION:
        raise CheckpointError(f"{ckpt_dir / 'config.json'}: version {doc.get('version')!r}, expected {VERSION}")
    try:
        config = ACTConfig.from_dict(doc.get("act"))
    except (TypeError, ValueError) as e:
        raise CheckpointError(f"{ckpt_dir / 'config.json'}: invalid ACT config: {e}") from None
    return config, doc.get("meta") or {}


def load_checkpoint(ckpt_dir: str | Path, device: str | torch.device = "cpu"
                    ) -> tuple[ACT, dict[str, np.ndarray], dict]:
    """Load (model in eval mode, tactile backgrounds by sensor, meta) from a checkpoint folder."""
    ckpt_dir = Path(ckpt_dir)
    config, meta = read_config(ckpt_dir)
    model = ACT(config)
    weights = ckpt_dir / "model.safetensors"
    if not weights.is_file():
        raise CheckpointError(f"checkpoint file missing: {weights}")
    try:
        state = load_file(str(weights))
    except (SafetensorError, OSError) as e:
        raise CheckpointError(f"{weights} is corrupted or not a safetensors file: {e}") from None
    expected = model.state_dict()
    missing, unexpected = sorted(set(expected) - set(state)), sorted(set(state) - set(expected))
    if missing or unexpected:
        raise CheckpointError(f"{weights} does not match config.json: missing {missing[:5]}, "
                              f"unexpected {unexpected[:5]}")
    for k, v in expected.items():
        if state[k].shape != v.shape:
            raise CheckpointError(f"{weights}: {k} has shape {tuple(state[k].shape)}, config.json implies "
                                  f"{tuple(v.shape)}")
        if state[k].is_floating_point() and not torch.isfinite(state[k]).all():
            raise CheckpointError(f"{weights}: {k} contains NaN or inf")
    model.load_state_dict(state)
    try:
        model.set_stats(_read_json(ckpt_dir / "stats.json"))
    except CheckpointError:
        raise
    except ValueError as e:
        raise CheckpointError(f"{ckpt_dir / 'stats.json'}: {e}") from None
    backgrounds: dict[str, np.ndarray] = {}
    bg_file = ckpt_dir / "tactile_background.safetensors"
    if bg_file.is_file():
        try:
            backgrounds = {k: v.numpy() for k, v in load_file(str(bg_file)).items()}
        except (SafetensorError, OSError) as e:
            raise CheckpointError(f"{bg_file} is corrupted: {e}") from None
    return model.to(device).eval(), backgrounds, meta
