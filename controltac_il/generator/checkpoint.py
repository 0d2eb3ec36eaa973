"""Generator checkpoints: the project's checkpoint convention (``controltac_il.checkpoint``) with two weight files.

Layout::

    config.json               GeneratorConfig.to_dict()
    autoencoder.safetensors   TactileAutoencoder state dict
    denoiser.safetensors      ForceDiT state dict
    model_card.json           provenance, measured figures and the weights' SHA-256 (verified at load)

A stage-2 pose-adapter folder holds ``config.json`` (PoseAdapterConfig), ``adapter.safetensors`` and its card.

Loading never unpickles anything; a missing file, a hash that differs from the card's or NaN / inf
weights raise CheckpointError naming the file, and a state dict that does not match the config's model
(missing or extra tensors, other shapes) raises one naming the tensors.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import torch

from controltac_il.checkpoint import (CARD_FILE, CONFIG_FILE, CheckpointError, load_folder, load_into,
                                      save_folder)
from controltac_il.config import one_line
from controltac_il.generator.adapter import PoseAdapter
from controltac_il.generator.autoencoder import TactileAutoencoder
from controltac_il.generator.config import GeneratorConfig, PoseAdapterConfig
from controltac_il.generator.dit import ForceDiT

AE_FILE = "autoencoder.safetensors"
DIT_FILE = "denoiser.safetensors"
WEIGHT_FILES = (AE_FILE, DIT_FILE)
__all__ = ["ADAPTER_FILE", "AE_FILE", "CARD_FILE", "CONFIG_FILE", "DIT_FILE", "WEIGHT_FILES", "CheckpointError",
           "checkpoint_hash", "load_adapter", "load_checkpoint", "save_adapter", "save_checkpoint"]


def _config(d: dict, where: Path) -> GeneratorConfig:
    try:
        return GeneratorConfig.from_dict(d)
    except ValueError as e:
        raise CheckpointError(f"{where}: invalid generator config: {one_line(e)}") from None


def save_checkpoint(path: str | Path, config: GeneratorConfig, autoencoder: TactileAutoencoder,
                    denoiser: ForceDiT, dtype: torch.dtype | None = None, model_card: dict | None = None) -> Path:
    """Write a complete checkpoint folder atomically (the folder appears only when complete)."""
    return save_folder(path, config.to_dict(), {AE_FILE: autoencoder, DIT_FILE: denoiser}, card=model_card, dtype=dtype)


def load_checkpoint(path: str | Path) -> tuple[GeneratorConfig, TactileAutoencoder, ForceDiT]:
    """Rebuild (config, autoencoder, denoiser) in float32 from a checkpoint folder."""
    path = Path(path)
    d, weights = load_folder(path, WEIGHT_FILES)
    config = _config(d, path / CONFIG_FILE)
    ae, dit = TactileAutoencoder(config.autoencoder), ForceDiT(config.dit)
    load_into(ae, weights[AE_FILE], path / AE_FILE)
    load_into(dit, weights[DIT_FILE], path / DIT_FILE)
    return config, ae.eval(), dit.eval()


def checkpoint_hash(path: str | Path, weight_files: tuple[str, ...] = WEIGHT_FILES) -> str:
    """SHA-256 (first 16 hex digits) over config.json and the weight files (a pose adapter's: ``(ADAPTER_FILE,)``):
    cache provenance (the model card, where the weights' own hashes are recorded, is not part of it)."""
    path = Path(path)
    h = hashlib.sha256()
    for name in (CONFIG_FILE, *weight_files):
        h.update(name.encode())
        h.update((path / name).read_bytes())
    return h.hexdigest()[:16]


# -- stage 2: the pose adapter (config.json = PoseAdapterConfig, adapter.safetensors, model card) -----------

ADAPTER_FILE = "adapter.safetensors"


def save_adapter(path: str | Path, config: PoseAdapterConfig, adapter: PoseAdapter, dtype: torch.dtype | None = None,
                 model_card: dict | None = None) -> Path:
    """Write a pose-adapter checkpoint folder atomically."""
    return save_folder(path, config.to_dict(), {ADAPTER_FILE: adapter}, card=model_card, dtype=dtype)


def load_adapter(path: str | Path) -> tuple[PoseAdapterConfig, PoseAdapter]:
    """Rebuild (config, adapter) in float32 from a pose-adapter checkpoint folder (verified like stage 1's)."""
    path = Path(path)
    d, weights = load_folder(path, (ADAPTER_FILE,))
    try:
        config = PoseAdapterConfig.from_dict(d)
    except ValueError as e:
        raise CheckpointError(f"{path / CONFIG_FILE}: invalid pose-adapter config: {one_line(e)}") from None
    adapter = PoseAdapter(config)
    load_into(adapter, weights[ADAPTER_FILE], path / ADAPTER_FILE)
    return config, adapter.eval()
