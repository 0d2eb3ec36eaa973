"""Generator checkpoints: a folder of safetensors weights + ``config.json`` (+ ``model_card.json``).

Layout::

    config.json               GeneratorConfig.to_dict()
    autoencoder.safetensors   TactileAutoencoder state dict
    denoiser.safetensors      ForceDiT state dict
    model_card.json           provenance and measured figures (optional)

Loading never unpickles anything; a state dict that does not match the config's model (missing or
extra tensors, other shapes) raises ValueError naming the tensors.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from controltac_il.generator.autoencoder import TactileAutoencoder
from controltac_il.generator.config import GeneratorConfig
from controltac_il.generator.dit import ForceDiT
from controltac_il.io import atomic_dir, atomic_path, write_json

CONFIG_FILE = "config.json"
AE_FILE = "autoencoder.safetensors"
DIT_FILE = "denoiser.safetensors"
CARD_FILE = "model_card.json"
WEIGHT_FILES = (AE_FILE, DIT_FILE)


def _state_to_save(module: torch.nn.Module, dtype: torch.dtype | None) -> dict[str, torch.Tensor]:
    out = {}
    for k, v in module.state_dict().items():
        v = v.detach().cpu()
        if dtype is not None and v.is_floating_point():
            v = v.to(dtype)
        out[k] = v.contiguous()
    return out


def save_module(module: torch.nn.Module, path: str | Path, dtype: torch.dtype | None = None) -> None:
    """Write ``module``'s state dict as safetensors atomically (floats cast to ``dtype`` if given)."""
    with atomic_path(path, suffix=".safetensors") as tmp:
        save_file(_state_to_save(module, dtype), str(tmp))


def load_state_into(module: torch.nn.Module, path: str | Path, what: str) -> None:
    """Load a safetensors state dict into ``module``, checking names and shapes first."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what}: weights file {path} not found")
    state = load_file(str(path))
    expected = module.state_dict()
    missing = sorted(set(expected) - set(state))
    extra = sorted(set(state) - set(expected))
    bad = sorted(k for k in set(expected) & set(state) if tuple(expected[k].shape) != tuple(state[k].shape))
    if missing or extra or bad:
        detail = []
        if missing:
            detail.append(f"missing {missing[:5]}{'...' if len(missing) > 5 else ''}")
        if extra:
            detail.append(f"unexpected {extra[:5]}{'...' if len(extra) > 5 else ''}")
        if bad:
            detail.append("shape mismatch " + ", ".join(
                f"{k}: file {tuple(state[k].shape)} vs config {tuple(expected[k].shape)}" for k in bad[:5]))
        raise ValueError(f"{what}: checkpoint {path} does not match the model built from its config ({'; '.join(detail)})")
    module.load_state_dict({k: v.to(expected[k].dtype) for k, v in state.items()}, strict=True)


def read_config(path: str | Path) -> GeneratorConfig:
    path = Path(path)
    f = path / CONFIG_FILE
    if not f.is_file():
        raise FileNotFoundError(f"generator checkpoint {path}: {CONFIG_FILE} not found")
    try:
        d = json.loads(f.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{f}: not valid JSON ({e})") from e
    return GeneratorConfig.from_dict(d)


def save_checkpoint(path: str | Path, config: GeneratorConfig, autoencoder: TactileAutoencoder,
                    denoiser: ForceDiT, dtype: torch.dtype | None = None, model_card: dict | None = None) -> Path:
    """Write a complete checkpoint folder atomically (the folder appears only when complete)."""
    path = Path(path)
    with atomic_dir(path) as tmp:
        write_json(tmp / CONFIG_FILE, config.to_dict())
        save_file(_state_to_save(autoencoder, dtype), str(tmp / AE_FILE))
        save_file(_state_to_save(denoiser, dtype), str(tmp / DIT_FILE))
        if model_card is not None:
            write_json(tmp / CARD_FILE, model_card)
    return path


def load_checkpoint(path: str | Path) -> tuple[GeneratorConfig, TactileAutoencoder, ForceDiT]:
    """Rebuild (config, autoencoder, denoiser) in float32 from a checkpoint folder."""
    path = Path(path)
    config = read_config(path)
    ae = TactileAutoencoder(config.autoencoder)
    dit = ForceDiT(config.dit)
    load_state_into(ae, path / AE_FILE, "autoencoder")
    load_state_into(dit, path / DIT_FILE, "denoiser")
    return config, ae.eval(), dit.eval()


def checkpoint_hash(path: str | Path) -> str:
    """SHA-256 (first 16 hex digits) over config.json and the weight files: cache provenance."""
    path = Path(path)
    h = hashlib.sha256()
    for name in (CONFIG_FILE, *WEIGHT_FILES):
        h.update(name.encode())
        h.update((path / name).read_bytes())
    return h.hexdigest()[:16]
