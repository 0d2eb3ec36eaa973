"""``ForceEstimator``: read [Fx, Fy, Fz] (N, sensor frame) from tactile residual images."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from controltac_il.arrays import as_array
from controltac_il.checkpoint import (CARD_FILE, CONFIG_FILE, HASH_KEY, CheckpointError, load_folder, load_into,
                                      read_json, save_folder)
from controltac_il.cli import RunFault
from controltac_il.config import is_int, one_line
from controltac_il.estimators.config import EstimatorConfig
from controltac_il.estimators.model import ForceCNN
from controltac_il.training import parse_device

DEFAULT_CHECKPOINT = Path(__file__).resolve().parent / "checkpoints" / "default"
WEIGHTS_FILE = "model.safetensors"
MODEL_NAME = "controltac-il force estimator (compact CNN: tactile residual -> [Fx, Fy, Fz] N)"


def validate_residuals(residuals, name: str = "residuals") -> np.ndarray:
    """Check a batch of residual images and return it as a numpy array (N, H, W, 3).

    Accepts uint8, or floats holding 0-255 values (finite, not all within [0, 1]); anything else raises
    ValueError naming ``name`` and the expected form. Frames that look like raw sensor frames, not residuals,
    are warned about (``_warn_if_raw``).
    """
    if isinstance(residuals, torch.Tensor):
        residuals = as_array(residuals)
    if not isinstance(residuals, np.ndarray):
        raise ValueError(f"{name} must be a numpy array (N, H, W, 3) uint8, got {type(residuals).__name__}")
    if residuals.ndim != 4 or residuals.shape[-1] != 3:
        raise ValueError(
            f"{name} must have shape (N, H, W, 3) (channels last, RGB), got {residuals.shape}; "
            "add a batch axis for a single frame"
        )
    n, h, w, _ = residuals.shape
    if n == 0 or h < 8 or w < 8:
        raise ValueError(f"{name} must hold at least one image of at least 8x8 pixels, got shape {residuals.shape}")
    if np.issubdtype(residuals.dtype, np.floating):
        if not np.isfinite(residuals).all():
            raise ValueError(f"{name} contains NaN or infinite values; expected 0-255 residual pixels")
        if residuals.min() < 0 or residuals.max() > 255:
            raise ValueError(
                f"{name} values must lie in [0, 255] (residual with 127 offset), got "
                f"[{residuals.min():.3g}, {residuals.max():.3g}]"
            )
        if residuals.max() <= 1:  # a residual sits at 127 away from contact: these are pixels scaled to [0, 1]
            raise ValueError(f"{name} values lie in [0, 1]; residual pixels are 0-255 (multiply by 255, or pass uint8)")
    elif residuals.dtype != np.uint8:
        raise ValueError(f"{name} must be uint8 (or float in [0, 255]), got dtype {residuals.dtype}")
    _warn_if_raw(residuals, name)
    return residuals


RAW_OFFSET = 20.0  # grey levels: a residual's typical pixel lies within ~2 of 127, a raw GelSight frame's 30 or more


def _warn_if_raw(residuals: np.ndarray, name: str) -> None:
    """Warn when most of (up to 16 of) the frames look like raw sensor frames, not residuals: the median pixel
    (every 8th row and column) more than RAW_OFFSET grey levels from 127. The estimator then reads 17-20 N off a
    frame without contact."""
    frames = residuals[:: max(1, len(residuals) // 16)][:16, ::8, ::8].astype(np.float32)
    offset = np.median(np.abs(frames - 127.0).max(axis=-1).reshape(len(frames), -1), axis=1)
    raw = int((offset > RAW_OFFSET).sum())
    if raw > len(frames) / 2:
        warnings.warn(f"{name}: {raw} of {len(frames)} frames sampled look like raw sensor frames, not residuals "
                      f"(median pixel {float(np.median(offset)):.0f} grey levels from 127); pass "
                      "to_residual(frames, background)", stacklevel=4)  # the caller of predict


def preprocess(residuals: np.ndarray | torch.Tensor, config: EstimatorConfig) -> torch.Tensor:
    """(N, H, W, 3) residual pixels -> network input (N, 3, h, w) float32, resized and normalised."""
    x = torch.as_tensor(residuals).permute(0, 3, 1, 2).float()
    size = (config.input_height, config.input_width)
    if tuple(x.shape[-2:]) != size:
        x = F.interpolate(x, size=size, mode="bilinear", antialias=True, align_corners=False)
    return (x - config.residual_offset) / config.residual_scale


def identity(weights_hash: str, config: EstimatorConfig) -> str:
    """What an estimator reads forces with, 16 hex: its weights' hash, or with a colour calibration the hash of
    both (one network under two sensors' calibrations gives two readings, so two caches)."""
    if config.input_mix is None:
        return weights_hash
    import hashlib
    import json

    text = json.dumps([weights_hash, config.input_mix, config.input_shift, "mix reads Fz only"])  # since Fx, Fy unmixed
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def colour_mix(x: torch.Tensor, mix: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """Input (N, 3, h, w) with its colour channels c mixed to ``mix`` (3, 3) @ c + ``shift`` (3,)."""
    return torch.einsum("ij,njhw->nihw", mix, x) + shift[None, :, None, None]


def mix_colours(x: torch.Tensor, config: EstimatorConfig) -> torch.Tensor:
    """Network input (N, 3, h, w) with the config's colour calibration applied (identity when it has none)."""
    if config.input_mix is None:
        return x
    return colour_mix(x, torch.tensor(config.input_mix, dtype=x.dtype, device=x.device),
                      torch.tensor(config.input_shift, dtype=x.dtype, device=x.device))


class ForceEstimator:
    """A trained :class:`ForceCNN` with its config; ``predict`` maps residuals to forces in N."""

    def __init__(self, config: EstimatorConfig, model: ForceCNN | None = None, device: str = "cpu"):
        self.config = config
        self.device = parse_device(device)
        self.model = (model or ForceCNN(config)).to(self.device).eval()
        self._mean = torch.tensor(config.force_mean, dtype=torch.float32, device=self.device)
        self._std = torch.tensor(config.force_std, dtype=torch.float32, device=self.device)

    # ---- force units <-> network outputs
    def normalise_forces(self, forces: torch.Tensor) -> torch.Tensor:
        return (forces.to(self.device) - self._mean) / self._std

    def denormalise_forces(self, outputs: torch.Tensor) -> torch.Tensor:
        return outputs * self._std + self._mean

    def contact_visible(self, residuals: np.ndarray) -> np.ndarray:
        """bool (N,): whether each residual (N, H, W, 3) shows contact by the config's gate."""
        thr = self.config.contact_threshold
        if thr is None:
            return np.ones(len(residuals), dtype=bool)
        out = np.empty(len(residuals), dtype=bool)
        for i, r in enumerate(residuals):
            magnitude = np.abs(r.astype(np.float32) - self.config.residual_offset).max(axis=-1)
            out[i] = (magnitude > thr).mean() >= self.config.min_contact_fraction
        return out

    @torch.no_grad()
    def predict(self, residuals, batch_size: int = 256, gate: bool = True) -> np.ndarray:
        """Forces [Fx, Fy, Fz] in N, sensor frame, float32 (N, 3) for residuals (N, H, W, 3).

        Any H, W is resized to the network's input size (same physical pad assumed). A colour calibration
        (``config.input_mix``, fitted on Fz labels) applies to Fz; Fx and Fy read the unmixed frame. With
        ``gate``, frames without visible contact (see ``EstimatorConfig.contact_threshold``) read
        exactly 0 N; ``gate=False`` returns the raw network reading for every frame. A reading that is not
        finite raises RunFault (the checkpoint is broken), never passed on.
        """
        if not is_int(batch_size) or batch_size < 1:
            raise ValueError(f"batch_size must be an int >= 1, got {batch_size!r}")
        residuals = validate_residuals(residuals)
        self.model.eval()
        out = []
        for i in range(0, len(residuals), batch_size):
            x = preprocess(residuals[i : i + batch_size], self.config).to(self.device)
            forces = self.denormalise_forces(self.model(x))
            if self.config.input_mix is not None:  # the colour calibration is fitted on Fz; Fx, Fy read the frame
                forces[:, 2] = self.denormalise_forces(self.model(mix_colours(x, self.config)))[:, 2]
            out.append(forces.cpu())
        forces = torch.cat(out).numpy().astype(np.float32)
        bad = ~np.isfinite(forces).all(axis=-1)
        if bad.any():  # a broken checkpoint: never a reference force of NaN passed on as a reading
            raise RunFault(f"the force estimator's output holds NaN or inf values for {int(bad.sum())} of {len(bad)} "
                           f"frames (e.g. index {int(np.flatnonzero(bad)[0])}); its checkpoint is broken: retrain "
                           "or recalibrate it")
        if gate:
            forces[~self.contact_visible(residuals)] = 0.0
        return forces

    # ---- checkpoints (the project's convention: controltac_il.checkpoint)
    def save(self, path: str | Path, card: str | None = None) -> Path:
        """Write ``model.safetensors`` + ``config.json`` + ``model_card.json`` (the weights' hash) and, if
        ``card``, ``README.md`` (the human-readable card) as one folder, atomically."""
        return save_folder(path, self.config.to_dict(), {WEIGHTS_FILE: self.model}, card={"model": MODEL_NAME},
                           files={"README.md": card} if card is not None else None)

    @classmethod
    def from_pretrained(cls, path: str | Path | None = None, device: str = "cpu") -> "ForceEstimator":
        """Load a checkpoint folder (weights verified against its model card), or the estimator of a calibration
        bundle (``python -m controltac_il.calibrate``: its ``estimator/``); ``None`` loads the shipped default."""
        path = Path(path) if path is not None else DEFAULT_CHECKPOINT
        if (path / BUNDLE_PART).is_dir() and not (path / WEIGHTS_FILE).is_file():
            path = path / BUNDLE_PART
        d, weights = load_folder(path, (WEIGHTS_FILE,))
        try:
            config = EstimatorConfig.from_dict(d)
        except ValueError as e:
            raise CheckpointError(f"{path / CONFIG_FILE}: invalid estimator config: {one_line(e)}") from None
        est = cls(config, device=device)
        load_into(est.model, weights[WEIGHTS_FILE], path / WEIGHTS_FILE)
        est.model.eval()
        est.checkpoint_hash = identity(read_json(path / CARD_FILE)[HASH_KEY][WEIGHTS_FILE][:16], config)  # verified
        return est

    checkpoint_hash: str | None = None


BUNDLE_PART = "estimator"  # a calibration bundle's estimator subfolder
