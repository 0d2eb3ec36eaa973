"""``ForceGenerator``: reference tactile residual + ΔF -> residual at the target force (inference API).

    gen = ForceGenerator.from_pretrained()                 # shipped default checkpoint
    out = gen.generate(reference_residuals, delta_force)   # uint8 (B, H, W, 3) in and out
    imgs = gen.generate_images(images, background, delta_force)

Pipeline: residual -> [-1, 1] -> encoder -> z_ref; DDIM samples the normalised latent delta
Δz = (z_target - z_ref) / delta_scale conditioned on (z_ref, ΔF); decode(z_ref + Δz) -> residual.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
import torch

from controltac_il.generator.autoencoder import TactileAutoencoder
from controltac_il.generator.checkpoint import checkpoint_hash, load_checkpoint
from controltac_il.generator.config import DETAIL_GATE_SIGMA_PX, FZ_RANGE, SHEAR_MAX, GeneratorConfig
from controltac_il.generator.dit import ForceDiT
from controltac_il.generator.sampler import ddim_sample, make_scheduler, seeded_noise

CHECKPOINT_ROOT = Path(__file__).resolve().parent / "checkpoints"
SHIPPED = ("default", "fast")
OUT_OF_RANGE_POLICIES = ("clamp", "error")
# Largest |ΔF| between two forces of the validated range, per component [Fx, Fy, Fz] (N).
MAX_DELTA = np.array([2 * SHEAR_MAX, 2 * SHEAR_MAX, FZ_RANGE[1] - FZ_RANGE[0]], dtype=np.float64)
RESIDUAL_OFFSET = 127.0


def residual_to_unit(residual: torch.Tensor) -> torch.Tensor:
    """uint8 residual (B, H, W, 3) -> float (B, 3, H, W), 127 -> 0, scale 1/128."""
    return (residual.permute(0, 3, 1, 2).float() - RESIDUAL_OFFSET) / 128.0


@dataclass
class RangeReport:
    """Validated-range bookkeeping of one ``generate`` call (and, summed, of a generator's life).

    total: samples seen; clamped: samples whose target force (or ΔF) was moved into the validated
    range (Fz in [1, 10] N, |Fx|, |Fy| <= 1 N; without reference forces |ΔF| is bounded by the
    range's span, [2, 2, 9] N).
    """

    total: int = 0
    clamped: int = 0
    clamped_indices: list[int] = field(default_factory=list)


def _resize_each(images: np.ndarray, size_wh: tuple[int, int]) -> np.ndarray:
    """Bilinear resize of each (H, W[, C]) float image to (width, height) = size_wh."""
    return np.stack([cv2.resize(x, size_wh, interpolation=cv2.INTER_LINEAR) for x in images])


def _validate_residuals(x, name: str) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    if not isinstance(x, np.ndarray):
        raise ValueError(f"{name} must be a uint8 array (B, H, W, 3), got {type(x).__name__}")
    if x.dtype != np.uint8:
        raise ValueError(f"{name} must have dtype uint8 (values 0-255), got {x.dtype}")
    if x.ndim != 4 or x.shape[-1] != 3 or x.shape[0] < 1 or min(x.shape[1:3]) < 8:
        raise ValueError(f"{name} must have shape (B, H, W, 3) with B >= 1 and H, W >= 8, got {x.shape}")
    return x


def _validate_forces(f, n: int, name: str) -> np.ndarray:
    try:
        f = np.asarray(f.detach().cpu() if isinstance(f, torch.Tensor) else f, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be a float array (B, 3) in N, got {f!r}") from e
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"{name} must have shape (B, 3) [Fx, Fy, Fz] in N, got {f.shape}")
    if f.shape[0] != n:
        raise ValueError(f"{name} has {f.shape[0]} rows but the batch has {n} reference residuals")
    if not np.all(np.isfinite(f)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return f


def locate_checkpoint(path: str | Path | None = None) -> Path:
    """The checkpoint folder ``from_pretrained(path)`` loads: ``None``/``"default"`` and ``"fast"`` name the shipped ones."""
    if path is None:
        path = "default"
    if isinstance(path, str) and path in SHIPPED:
        path = CHECKPOINT_ROOT / path
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"generator checkpoint folder {path} not found")
    return path


class ForceGenerator:
    """Stage-1 force-control generator (autoencoder + ΔF-conditioned DiT + DDIM)."""

    def __init__(self, config: GeneratorConfig, autoencoder: TactileAutoencoder, denoiser: ForceDiT,
                 device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32, checkpoint_hash: str = "untracked"):
        if dtype not in (torch.float32, torch.bfloat16, torch.float16):
            raise ValueError(f"dtype must be torch.float32, torch.bfloat16 or torch.float16, got {dtype}")
        self.config = config
        self.device = torch.device(device)
        self.dtype = dtype
        self.autoencoder = autoencoder.to(self.device, dtype).eval()
        self.denoiser = denoiser.to(self.device, dtype).eval()
        self.checkpoint_hash = checkpoint_hash
        self.range_report = RangeReport()
        self.last_range_report = RangeReport()
        c = config.autoencoder.latent_channels
        self._latent_scale = torch.tensor(config.latent_scale, device=self.device).view(1, c, 1, 1)
        self._delta_scale = torch.tensor(config.delta_scale, device=self.device).view(1, c, 1, 1)

    @classmethod
    def from_pretrained(cls, path: str | Path | None = None, device: str | torch.device = "cpu",
                        dtype: torch.dtype = torch.float32) -> "ForceGenerator":
        """Load a checkpoint folder; ``None`` or ``"default"`` = the shipped default, ``"fast"`` = the faster variant."""
        path = locate_checkpoint(path)
        config, ae, dit = load_checkpoint(path)
        return cls(config, ae, dit, device=device, dtype=dtype, checkpoint_hash=checkpoint_hash(path))

    # -- force range -------------------------------------------------------------------------
    def _apply_range(self, delta: np.ndarray, reference_force: np.ndarray | None, out_of_range: str) -> np.ndarray:
        if out_of_range not in OUT_OF_RANGE_POLICIES:
            raise ValueError(f"out_of_range must be one of {OUT_OF_RANGE_POLICIES}, got {out_of_range!r}")
        tol = 1e-6  # N: float32 round trips of in-range values are not clamps
        if reference_force is not None:
            target = reference_force + delta
            lo = np.array([-SHEAR_MAX, -SHEAR_MAX, FZ_RANGE[0]])
            hi = np.array([SHEAR_MAX, SHEAR_MAX, FZ_RANGE[1]])
            outside = (target < lo - tol) | (target > hi + tol)
            fixed = np.where(outside, np.clip(target, lo, hi) - reference_force, delta)
            what = "target force reference_force + delta_force"
        else:
            outside = np.abs(delta) > MAX_DELTA + tol
            fixed = np.where(outside, np.clip(delta, -MAX_DELTA, MAX_DELTA), delta)
            what = "delta_force"
        bad = np.flatnonzero(outside.any(axis=1))
        report = RangeReport(total=len(delta), clamped=len(bad), clamped_indices=bad.tolist())
        if len(bad) and out_of_range == "error":
            raise ValueError(
                f"{len(bad)} of {len(delta)} samples have a {what} outside the validated range "
                f"(Fz in {list(FZ_RANGE)} N, |Fx|, |Fy| <= {SHEAR_MAX} N), e.g. index {bad[0]}; "
                "pass out_of_range='clamp' to move them into range")
        if len(bad):
            warnings.warn(f"clamped {len(bad)} of {len(delta)} samples whose {what} was outside the validated range",
                          stacklevel=3)
        self.last_range_report = report
        self.range_report.total += report.total
        self.range_report.clamped += report.clamped
        return fixed

    # -- model steps ---------------------------------------------------------------------------
    @torch.no_grad()
    def encode(self, residuals: torch.Tensor) -> torch.Tensor:
        """uint8 (B, H, W, 3) at the model size -> normalised reference latent (B, C, h, w)."""
        x = residual_to_unit(residuals.to(self.device)).to(self.dtype)
        return (self.autoencoder.encode(x).float() / self._latent_scale).to(self.dtype)

    @torch.no_grad()
    def _decode(self, z_ref_n: torch.Tensor, delta_n: torch.Tensor) -> tuple[np.ndarray, np.ndarray | None]:
        """Decoded target and (when anchoring) decoded reference, grey levels about 0, (b, H, W, 3) float32."""
        def decode(z):
            return self.autoencoder.decode(z.to(self.dtype)).float().permute(0, 2, 3, 1).cpu().numpy() * 128.0
        target = decode(z_ref_n.float() * self._latent_scale + delta_n.float() * self._delta_scale)
        if not self.config.anchor_to_reference:
            return target, None
        return target, decode(z_ref_n.float() * self._latent_scale)

    def _detail_weight(self, target: np.ndarray, recon: np.ndarray) -> np.ndarray:
        """Share of the reference's detail to keep, (b, H, W, 1) in [0, 1] (see GeneratorConfig.detail_gate)."""
        g = self.config.detail_gate
        if g == 0:
            return np.ones((*target.shape[:3], 1), np.float32)
        def magnitude(x):
            return np.stack([cv2.GaussianBlur(np.abs(m).mean(-1), (0, 0), DETAIL_GATE_SIGMA_PX) for m in x])
        return np.clip((magnitude(target) + g) / (magnitude(recon) + g), 0.0, 1.0)[..., None]

    # -- public API ----------------------------------------------------------------------------
    def generate(self, reference_residuals, delta_force, steps: int | None = None, seed: int | Sequence[int] = 0,
                 batch_size: int = 32, reference_force=None, out_of_range: str = "clamp") -> np.ndarray:
        """Residuals at the target force: uint8 (B, H, W, 3), same size as the input.

        reference_residuals: uint8 (B, H, W, 3) residual images (``to_residual``); any H, W (resized to
            the model's size and back). delta_force: (B, 3) [ΔFx, ΔFy, ΔFz] N = F_target - F_reference.
        steps: DDIM steps (>= 1), default ``config.default_steps``. seed: one int (every sample uses the
            same noise, so a sample's output never depends on its batch-mates) or B ints (one per sample).
        batch_size: samples per forward pass (memory only; results do not depend on it).
        reference_force: optional (B, 3) N; then targets outside the validated range are handled by
            ``out_of_range`` ("clamp" moves the target into range, "error" raises); without it the
            same applies to ΔF beyond the range's span. Either way the count is kept in
            ``last_range_report`` / ``range_report``.
        """
        ref = _validate_residuals(reference_residuals, "reference_residuals")
        n = ref.shape[0]
        delta = _validate_forces(delta_force, n, "delta_force")
        ref_f = None if reference_force is None else _validate_forces(reference_force, n, "reference_force")
        steps = self.config.default_steps if steps is None else steps
        if not isinstance(steps, (int, np.integer)) or isinstance(steps, bool) or not 1 <= steps <= self.config.diffusion.num_train_timesteps:
            raise ValueError(f"steps must be an int in [1, {self.config.diffusion.num_train_timesteps}], got {steps!r}")
        if not isinstance(batch_size, (int, np.integer)) or isinstance(batch_size, bool) or batch_size < 1:
            raise ValueError(f"batch_size must be a positive int, got {batch_size!r}")
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed)] * n
        else:
            seeds = [int(s) for s in seed]
            if len(seeds) != n:
                raise ValueError(f"seed must be one int or {n} ints (one per sample), got {len(seeds)}")
        delta = self._apply_range(delta, ref_f, out_of_range)

        h_in, w_in = ref.shape[1:3]
        H, W = self.config.image_size
        resized = (h_in, w_in) != (H, W)
        model_in = np.stack([cv2.resize(r, (W, H), interpolation=cv2.INTER_AREA) for r in ref]) if resized else ref
        lh, lw = self.config.autoencoder.latent_size
        noise = seeded_noise(seeds, (self.config.autoencoder.latent_channels, lh, lw))
        scheduler = make_scheduler(self.config.diffusion)
        out = np.empty_like(ref)
        for s in range(0, n, batch_size):
            e = min(n, s + batch_size)
            z_ref = self.encode(torch.from_numpy(model_in[s:e]))
            df = torch.from_numpy(delta[s:e]).float().to(self.device)
            d = ddim_sample(self.denoiser, scheduler, z_ref, df, noise[s:e].to(self.device), int(steps))
            target, recon = self._decode(z_ref, d)
            keep = None if recon is None else self._detail_weight(target, recon)
            if resized:
                target = _resize_each(target, (w_in, h_in))
                if recon is not None:
                    recon, keep = _resize_each(recon, (w_in, h_in)), _resize_each(keep[..., 0], (w_in, h_in))[..., None]
            y = target + RESIDUAL_OFFSET
            if recon is not None:  # the reference's detail (reference - its reconstruction), gated
                y = y + keep * (ref[s:e].astype(np.float32) - RESIDUAL_OFFSET - recon)
            out[s:e] = np.clip(np.round(y), 0, 255).astype(np.uint8)
        return out

    def generate_images(self, images, background, delta_force, **kwargs) -> np.ndarray:
        """Raw tactile images in, raw images out: uint8 (B, H, W, 3) with a (H, W, 3) no-contact background.

        Subtracts the background with the 127 offset, calls ``generate`` (same keyword options), adds it back.
        """
        from controltac_il.tactile import from_residual, to_residual

        images = _validate_residuals(images, "images")
        background = np.asarray(background)
        if background.dtype != np.uint8 or background.shape != images.shape[1:]:
            raise ValueError(f"background must be uint8 of shape {images.shape[1:]}, got {background.dtype} {background.shape}")
        residuals = np.stack([to_residual(im, background) for im in images])
        out = self.generate(residuals, delta_force, **kwargs)
        return np.stack([from_residual(r, background) for r in out])
