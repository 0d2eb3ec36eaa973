"""``ForceGenerator``: reference tactile residual + ΔF -> residual at the target force (inference API).

    gen = ForceGenerator.from_pretrained()                 # shipped default checkpoint
    out = gen.generate(reference_residuals, delta_force)   # uint8 (B, H, W, 3) in and out
    res = gen.generate_at(residuals, reference_force, target_force)  # res.residuals, res.decision
    imgs = gen.generate_images(images, background, delta_force)
    gen = ForceGenerator.from_pretrained(pose_adapter="pose")  # with stage 2, the pose adapter
    out = gen.generate(reference_residuals, delta_force, object_mask=masks, transform=(dx_px, dy_px, dtheta))

Targets outside the validated range (``forces.VALIDATED_RANGE``) are decided here and only here
(``forces.decide_targets``: clamp, skip or error); ``generate_at`` returns the decision per sample.
Inputs the model was never validated on are refused rather than run: reference forces outside that
range (``out_of_range="skip"`` keeps such samples unchanged instead), NaN/inf forces, non-uint8 images,
and images whose aspect ratio differs from the model's by more than ``MAX_ASPECT_CHANGE`` (the resize to
the model's size would distort every contact).

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

from controltac_il.cli import RunFault
from controltac_il.generator.adapter import PoseAdapter, PoseControlledDenoiser, masks_to_model
from controltac_il.generator.autoencoder import TactileAutoencoder
from controltac_il.generator.checkpoint import ADAPTER_FILE, checkpoint_hash, load_adapter, load_checkpoint
from controltac_il.generator.config import DETAIL_GATE_SIGMA_PX, GeneratorConfig
from controltac_il.generator.dit import ForceDiT
from controltac_il.generator.forces import VALIDATED_RANGE, TargetDecision, decide_targets
from controltac_il.generator.sampler import ddim_sample, make_scheduler, seeded_noise
from controltac_il.generator.shipped import SHIPPED_ADAPTERS, locate_checkpoint
from controltac_il.tactile.pose import check_mask, move_mask
from controltac_il.tactile.residual import OFFSET

RESIDUAL_OFFSET = float(OFFSET)
# Largest change of aspect ratio (either way) the resize to the model's image size may make.
MAX_ASPECT_CHANGE = 1.5
# Every forward pass runs whole chunks of this many rows, the last padded by repeating its last row: CPU kernels
# round a 1-3-row product or convolution differently (the shipped DiT's conditioning, a small autoencoder's
# convolutions), so without it a sample's bytes depended on how many batch-mates it had. Costs online mode (one
# frame a call) the chunk's compute (tests/test_gen_api.py, tests/test_aug_lerobot.py pin the equality).
GENERATION_CHUNK = 4


def residual_to_unit(residual: torch.Tensor) -> torch.Tensor:
    """uint8 residual (B, H, W, 3) -> float (B, 3, H, W), 127 -> 0, scale 1/128."""
    return (residual.permute(0, 3, 1, 2).float() - RESIDUAL_OFFSET) / 128.0


class NonFiniteOutput(RunFault):
    """The generator's output held NaN or inf (a checkpoint trained into NaN, or beyond its dtype's range)."""


@dataclass
class RangeReport:
    """Validated-range bookkeeping of one ``generate`` call (and, summed, of a generator's life).

    total: samples seen; clamped: samples whose target force (or ΔF) was moved into the validated
    range (``forces.VALIDATED_RANGE``; without reference forces |ΔF| is bounded by the range's span);
    skipped: samples left ungenerated (``out_of_range="skip"``).
    """

    total: int = 0
    clamped: int = 0
    clamped_indices: list[int] = field(default_factory=list)
    skipped: int = 0


@dataclass(frozen=True)
class Generation:
    """What ``generate_at`` returns: the residuals and what was done with each requested target.

    residuals: uint8 (B, H, W, 3); a skipped sample's is its reference residual, unchanged.
    decision: the ``TargetDecision`` (requested and used target force, clamped, skipped per sample).
    """

    residuals: np.ndarray
    decision: TargetDecision


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


def _check_aspect(x: np.ndarray, model_hw: tuple[int, int], name: str) -> None:
    """Refuse images whose resize to the model's (H, W) would change the aspect ratio by more than
    ``MAX_ASPECT_CHANGE`` (a 240x20 strip squeezed to 128x160 is a 15x anisotropic resize)."""
    h, w = x.shape[1:3]
    mh, mw = model_hw
    change = (w / h) / (mw / mh)
    change = max(change, 1.0 / change)
    if change > MAX_ASPECT_CHANGE:
        raise ValueError(
            f"{name}: {h}x{w} (HxW) images would be resized to the model's {mh}x{mw} with a {change:.1f}x aspect "
            f"change (at most {MAX_ASPECT_CHANGE:g}x is allowed: the model would see distorted contacts); crop or "
            f"pad them to the model's {mh}:{mw} aspect first")


def _stack_masks(value, n: int, hw: tuple[int, int], name: str) -> np.ndarray:
    """One (H, W) mask for every sample or (B, H, W), each checked (``tactile.pose.check_mask``) -> bool (B, H, W)."""
    a = np.asarray(value.detach().cpu() if isinstance(value, torch.Tensor) else value)
    if a.ndim == 2:
        a = np.broadcast_to(a, (n, *a.shape))
    if a.ndim != 3 or a.shape[0] != n:
        raise ValueError(f"{name} must be (H, W) or ({n}, H, W) (one per reference), got shape {a.shape}")
    return np.stack([check_mask(m, hw, f"{name}[{i}]") for i, m in enumerate(a)])


def target_masks(n: int, hw: tuple[int, int], mask=None, object_mask=None, transform=None) -> np.ndarray | None:
    """The stage-2 condition of ``generate``: bool (B, H, W) contact masks at the target pose, or None (stage 1).

    ``mask``: the target pose's contact mask(s) as given; ``object_mask`` + ``transform``: the object's mask(s) at
    the reference pose moved by (dx_px, dy_px, dtheta) each (``tactile.pose.move_mask``)."""
    if mask is not None and (object_mask is not None or transform is not None):
        raise ValueError("give either mask (at the target pose) or object_mask with transform, not both")
    if (object_mask is None) != (transform is None):
        raise ValueError("object_mask and transform go together (the mask at the reference pose and its move)")
    if mask is not None:
        return _stack_masks(mask, n, hw, "mask")
    if object_mask is None:
        return None
    masks = _stack_masks(object_mask, n, hw, "object_mask")
    try:
        t = np.asarray(transform, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"transform must be (3,) or ({n}, 3) [dx_px, dy_px, dtheta_rad], got {transform!r}") from None
    t = np.broadcast_to(t, (n, 3)) if t.shape == (3,) else t
    if t.shape != (n, 3) or not np.isfinite(t).all():
        raise ValueError(f"transform must be finite (3,) or ({n}, 3) [dx_px, dy_px, dtheta_rad], got shape {t.shape}")
    return np.stack([move_mask(m, ti, name=f"object_mask[{i}]") for i, (m, ti) in enumerate(zip(masks, t))])


class ForceGenerator:
    """Force-control generator (autoencoder + ΔF-conditioned DiT + DDIM), with the optional stage-2 pose adapter
    (``pose_adapter``; ``load_pose_adapter``) that moves the contact to a target pose given as a contact mask."""

    def __init__(self, config: GeneratorConfig, autoencoder: TactileAutoencoder, denoiser: ForceDiT,
                 device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32, checkpoint_hash: str = "untracked",
                 pose_adapter: PoseAdapter | None = None):
        if dtype not in (torch.float32, torch.bfloat16, torch.float16):
            raise ValueError(f"dtype must be torch.float32, torch.bfloat16 or torch.float16, got {dtype}")
        self.config = config
        self.device = torch.device(device)
        self.dtype = dtype
        self.autoencoder = autoencoder.to(self.device, dtype).eval()
        self.denoiser = denoiser.to(self.device, dtype).eval()
        self.checkpoint_hash = checkpoint_hash
        self.pose_adapter, self.pose_adapter_hash = None, None
        if pose_adapter is not None:
            self._check_adapter(pose_adapter.config, "the pose adapter")
            self.pose_adapter, self.pose_adapter_hash = pose_adapter.to(self.device, dtype).eval(), "untracked"
        self.range_report = RangeReport()
        self.last_range_report = RangeReport()
        c = config.autoencoder.latent_channels
        self._latent_scale = torch.tensor(config.latent_scale, device=self.device).view(1, c, 1, 1)
        self._delta_scale = torch.tensor(config.delta_scale, device=self.device).view(1, c, 1, 1)

    @classmethod
    def from_pretrained(cls, path: str | Path | None = None, device: str | torch.device = "cpu",
                        dtype: torch.dtype = torch.float32, pose_adapter: str | Path | None = None) -> "ForceGenerator":
        """Load a checkpoint folder, or a shipped preset: ``None`` or ``"default"``, ``"fast"`` (faster, twice the
        error) or ``"quality"`` (a 9.9 M-parameter DiT: the lowest error, slower); docs/generator.md has the frontier.
        ``pose_adapter``: also load a stage-2 adapter (a folder, or ``"pose"``, shipped for the default)."""
        path = locate_checkpoint(path)
        config, ae, dit = load_checkpoint(path)
        gen = cls(config, ae, dit, device=device, dtype=dtype, checkpoint_hash=checkpoint_hash(path))
        return gen if pose_adapter is None else gen.load_pose_adapter(pose_adapter)

    def load_pose_adapter(self, path: str | Path = "pose") -> "ForceGenerator":
        """Attach a stage-2 pose adapter (a folder, or ``"pose"``); it must have been trained on this generator's
        checkpoint (its recorded base hash), else ValueError. Returns self."""
        folder = locate_checkpoint(path, SHIPPED_ADAPTERS)
        config, adapter = load_adapter(folder)
        if config.base_hash != self.checkpoint_hash:
            raise ValueError(f"pose adapter {folder} was trained on stage-1 checkpoint {config.base_hash or 'unknown'} "
                             f"(its config.json), this generator is {self.checkpoint_hash}: load the one it was trained on")
        self._check_adapter(config, f"pose adapter {folder}")
        self.pose_adapter = adapter.to(self.device, self.dtype).eval()
        self.pose_adapter_hash = checkpoint_hash(folder, (ADAPTER_FILE,))
        return self

    def _check_adapter(self, config, what: str) -> None:
        """An adapter fits this generator: built for its config, and no plain anchoring (which would paste the
        reference's detail back at the old pose: a ghost contact)."""
        if config.base != self.config:
            raise ValueError(f"{what} was built for another stage-1 configuration than this generator's")
        if self.config.anchor_to_reference and self.config.detail_gate == 0:
            raise ValueError(f"{what}: stage 2 needs a stage-1 generator with detail_gate > 0 or without anchoring "
                             "(plain anchoring would keep the reference's contact at its old pose)")

    def numerics(self) -> dict:
        """What decides the output bytes besides the inputs, the weights and the seeds: device, dtype and (CPU)
        torch's intra-op thread count, which changes a few values in a billion by one grey level. The batch does
        not (forward passes of whole ``GENERATION_CHUNK`` rows). A ForceAugment cache records it."""
        threads = torch.get_num_threads() if self.device.type == "cpu" else None
        return {"device": self.device.type, "dtype": str(self.dtype).removeprefix("torch."), "intra_op_threads": threads}

    # -- force range -------------------------------------------------------------------------
    def resolve_targets(self, target_force, out_of_range: str = "clamp", reference_force=None,
                        reference_out_of_range: str | None = None) -> TargetDecision:
        """What ``generate_at`` would do with these target forces (B, 3) N (and, when given, these reference
        forces), without generating or counting."""
        n = np.shape(target_force)[0] if np.ndim(target_force) else -1
        ref_f = None if reference_force is None else _validate_forces(reference_force, n, "reference_force")
        return decide_targets(_validate_forces(target_force, n, "target_force"), out_of_range,
                              reference_force=ref_f, reference_out_of_range=reference_out_of_range)

    def _count(self, decision: TargetDecision) -> None:
        bad = np.flatnonzero(decision.clamped)
        self.last_range_report = RangeReport(total=len(decision.clamped), clamped=len(bad),
                                             clamped_indices=bad.tolist(), skipped=int(decision.skipped.sum()))
        self.range_report.total += self.last_range_report.total
        self.range_report.clamped += self.last_range_report.clamped
        self.range_report.skipped += self.last_range_report.skipped

    def _resolve_delta(self, delta: np.ndarray, reference_force: np.ndarray | None,
                       out_of_range: str) -> tuple[np.ndarray, np.ndarray]:
        """(ΔF to condition on, bool (B,) samples to generate) of ``generate``: with reference forces the
        target reference + ΔF goes through ``decide_targets`` (components it moved get the new ΔF, the
        others keep theirs exactly); without, ΔF is bounded by the range's span. Counts; warns on clamps."""
        if reference_force is not None:
            what = "target force reference_force + delta_force"
            decision = decide_targets(reference_force + delta, out_of_range, what=what, reference_force=reference_force)
            fixed = np.where(decision.target != decision.requested, decision.target - reference_force, delta)
        else:
            what = "delta_force"
            decision = decide_targets(delta, out_of_range, VALIDATED_RANGE.delta_range(), what=what)
            fixed = decision.target
        self._count(decision)
        if decision.clamped.any():
            warnings.warn(f"clamped {int(decision.clamped.sum())} of {len(delta)} samples whose {what} was outside "
                          "the validated range", stacklevel=3)
        return fixed, decision.generated

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
                 batch_size: int = 32, reference_force=None, out_of_range: str = "clamp", mask=None,
                 object_mask=None, transform=None) -> np.ndarray:
        """Residuals at the target force: uint8 (B, H, W, 3), same size as the input.

        reference_residuals: uint8 (B, H, W, 3) residual images (``to_residual``); any H, W (resized to
            the model's size and back). delta_force: (B, 3) [ΔFx, ΔFy, ΔFz] N = F_target - F_reference.
        steps: DDIM steps (>= 1), default ``config.default_steps``. seed: one int (every sample uses the
            same noise, so a sample's output never depends on its batch-mates) or B ints (one per sample).
        batch_size: samples resized and blended together, rounded up to whole ``GENERATION_CHUNK``
            rows; the networks run one chunk at a time (memory only: a sample's bytes depend neither on it nor on
            its batch-mates; they do, rarely, on torch's thread count: ``numerics``).
        reference_force: optional (B, 3) N; then targets outside the validated range
            (``forces.VALIDATED_RANGE``) are handled by ``out_of_range`` ("clamp" moves the target into
            range, "error" raises, "skip" returns the reference unchanged); without it the same applies
            to ΔF beyond the range's span. Either way the count is kept in ``last_range_report`` /
            ``range_report``. A reference force outside the range is refused (ValueError) unless
            out_of_range="skip", which returns that sample's reference unchanged. ``generate_at`` takes
            target forces and says what it did per sample.
        Images whose aspect ratio differs from the model's by more than ``MAX_ASPECT_CHANGE`` are refused.
        Stage 2 (needs ``pose_adapter``): ``mask``, the contact mask at the target pose, bool or 0/1 (H, W) for
            all or (B, H, W), at the references' size; or ``object_mask`` (the contact at the reference pose, e.g.
            ``tactile.contact_mask`` of the reference) with ``transform`` (3,) or (B, 3) = (dx_px, dy_px, dtheta):
            rotate by dtheta rad counter-clockwise as displayed about the mask's centroid, then shift dx_px
            columns right and dy_px rows down (``tactile.pose``). The output shows the contact at that pose and
            the target force. Empty masks, masks of another size and moves that leave nothing on the pad are
            refused (ValueError). Without a mask: exactly stage 1.
        """
        ref = _validate_residuals(reference_residuals, "reference_residuals")
        _check_aspect(ref, self.config.image_size, "reference_residuals")
        n = ref.shape[0]
        delta = _validate_forces(delta_force, n, "delta_force")
        ref_f = None if reference_force is None else _validate_forces(reference_force, n, "reference_force")
        steps, seeds = self._check_options(steps, seed, batch_size, n)
        masks = self._target_masks(n, ref.shape[1:3], mask, object_mask, transform)
        delta, keep = self._resolve_delta(delta, ref_f, out_of_range)
        return self._sample_where(ref, delta, seeds, steps, batch_size, keep, masks)

    def generate_at(self, reference_residuals, reference_force, target_force, steps: int | None = None,
                    seed: int | Sequence[int] = 0, batch_size: int = 32, out_of_range: str = "clamp",
                    reference_out_of_range: str | None = None, mask=None, object_mask=None,
                    transform=None) -> Generation:
        """Residuals at ``target_force`` (B, 3) N from residuals at ``reference_force`` (B, 3) N, and what was done.

        Each requested target goes through ``forces.decide_targets`` once: "clamp" (default) moves a target
        outside the validated range into it, "skip" leaves that sample ungenerated (its reference residual
        is returned), "error" raises. The model is conditioned on ΔF = target used - reference. A
        ``reference_force`` outside the validated range cannot be moved (the image shows that force) and the
        model was not validated on it: ``reference_out_of_range`` "error" refuses it (ValueError), "skip"
        returns that sample's reference unchanged (``decision.reference_outside``); None (default) = "skip"
        under out_of_range="skip", else "error". Other arguments (the stage-2 mask ones too) as ``generate``;
        no warning is issued (the returned decision says what was clamped or skipped).
        """
        ref = _validate_residuals(reference_residuals, "reference_residuals")
        _check_aspect(ref, self.config.image_size, "reference_residuals")
        n = ref.shape[0]
        ref_f = _validate_forces(reference_force, n, "reference_force")
        target = _validate_forces(target_force, n, "target_force")
        steps, seeds = self._check_options(steps, seed, batch_size, n)
        masks = self._target_masks(n, ref.shape[1:3], mask, object_mask, transform)
        decision = decide_targets(target, out_of_range, reference_force=ref_f,
                                  reference_out_of_range=reference_out_of_range)
        self._count(decision)
        out = self._sample_where(ref, decision.target - ref_f, seeds, steps, batch_size, decision.generated, masks)
        return Generation(residuals=out, decision=decision)

    def _target_masks(self, n: int, hw: tuple[int, int], mask, object_mask, transform) -> np.ndarray | None:
        masks = target_masks(n, hw, mask, object_mask, transform)
        if masks is not None and self.pose_adapter is None:
            raise ValueError("a target-pose mask needs the stage-2 pose adapter: "
                             "ForceGenerator.from_pretrained(pose_adapter='pose') or gen.load_pose_adapter()")
        return masks

    def _check_options(self, steps, seed, batch_size, n: int) -> tuple[int, list[int]]:
        steps = self.config.default_steps if steps is None else steps
        if not isinstance(steps, (int, np.integer)) or isinstance(steps, bool) or not 1 <= steps <= self.config.diffusion.num_train_timesteps:
            raise ValueError(f"steps must be an int in [1, {self.config.diffusion.num_train_timesteps}], got {steps!r}")
        if not isinstance(batch_size, (int, np.integer)) or isinstance(batch_size, bool) or batch_size < 1:
            raise ValueError(f"batch_size must be a positive int, got {batch_size!r}")
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            return int(steps), [int(seed)] * n
        seeds = [int(s) for s in seed]
        if len(seeds) != n:
            raise ValueError(f"seed must be one int or {n} ints (one per sample), got {len(seeds)}")
        return int(steps), seeds

    def _sample_where(self, ref: np.ndarray, delta: np.ndarray, seeds: list[int], steps: int, batch_size: int,
                      keep: np.ndarray, masks: np.ndarray | None = None) -> np.ndarray:
        """``_sample`` on the rows ``keep`` selects (batched among themselves); the other rows stay ``ref``."""
        if keep.all():
            return self._sample(ref, delta, seeds, steps, batch_size, masks)
        out = ref.copy()
        rows = np.flatnonzero(keep)
        if len(rows):
            out[rows] = self._sample(ref[rows], delta[rows], [seeds[i] for i in rows], steps, batch_size,
                                     None if masks is None else masks[rows])
        return out

    def _sample(self, ref: np.ndarray, delta: np.ndarray, seeds: list[int], steps: int, batch_size: int,
                masks: np.ndarray | None = None) -> np.ndarray:
        """The model: residuals uint8 (B, H, W, 3) conditioned on ΔF (B, 3) N (and, with stage 2, target-pose
        masks bool (B, H, W)) -> residuals, same size. Forward passes of whole ``GENERATION_CHUNK`` rows (the
        last padded), so a row's bytes never depend on its batch-mates."""
        n = ref.shape[0]
        pad = -n % GENERATION_CHUNK
        if pad:
            ref, delta = (np.concatenate([x, x[-1:].repeat(pad, 0)]) for x in (ref, delta))
            seeds = list(seeds) + [seeds[-1]] * pad
            masks = None if masks is None else np.concatenate([masks, masks[-1:].repeat(pad, 0)])
        batch_size = -(-batch_size // GENERATION_CHUNK) * GENERATION_CHUNK
        H, W = self.config.image_size
        resized = ref.shape[1:3] != (H, W)
        model_in = np.stack([cv2.resize(r, (W, H), interpolation=cv2.INTER_AREA) for r in ref]) if resized else ref
        lh, lw = self.config.autoencoder.latent_size
        noise = seeded_noise(seeds, (self.config.autoencoder.latent_channels, lh, lw))
        out = np.empty_like(ref)
        for s in range(0, len(ref), batch_size):
            e = min(len(ref), s + batch_size)
            out[s:e] = self._forward(ref[s:e], model_in[s:e], delta[s:e], noise[s:e], steps,
                                     None if masks is None else masks[s:e])
        return out[:n]

    def _forward(self, ref: np.ndarray, model_in: np.ndarray, delta: np.ndarray, noise: torch.Tensor, steps: int,
                 masks: np.ndarray | None) -> np.ndarray:
        """One step of ``batch_size`` rows: residuals uint8 (b, H_in, W_in, 3) and their model-size copies ->
        residuals. The networks run on ``GENERATION_CHUNK`` rows at a time: a pass of one shape whatever the batch
        size, so torch picks the same kernels for it (on some CPUs it picks others by batch size)."""
        H, W = self.config.image_size
        h_in, w_in = ref.shape[1:3]
        c = GENERATION_CHUNK
        parts = [self._networks(model_in[i:i + c], delta[i:i + c], noise[i:i + c], steps,
                                None if masks is None else masks[i:i + c]) for i in range(0, len(ref), c)]
        target = np.concatenate([t for t, _ in parts])
        recon = None if parts[0][1] is None else np.concatenate([r for _, r in parts])
        keep = None if recon is None else self._detail_weight(target, recon)
        if (h_in, w_in) != (H, W):
            target = _resize_each(target, (w_in, h_in))
            if recon is not None:
                recon, keep = _resize_each(recon, (w_in, h_in)), _resize_each(keep[..., 0], (w_in, h_in))[..., None]
        y = target + RESIDUAL_OFFSET
        if recon is not None:  # the reference's detail (reference - its reconstruction), gated
            y = y + keep * (ref.astype(np.float32) - RESIDUAL_OFFSET - recon)
        bad = int(y.size - np.isfinite(y).sum())
        if bad:  # uint8 would make NaN a black pixel, silently
            dtype = str(self.dtype).removeprefix("torch.")
            raise NonFiniteOutput(f"the generator's output holds {bad} NaN or inf values ({dtype} on {self.device}); "
                                  "nothing was returned: check the checkpoint, or run in float32")
        return np.clip(np.round(y), 0, 255).astype(np.uint8)

    def _networks(self, model_in: np.ndarray, delta: np.ndarray, noise: torch.Tensor, steps: int,
                  masks: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """Encode, sample ΔF's latent and decode one chunk: model-size residuals uint8 (c, H, W, 3), ΔF (c, 3) N,
        noise (c, C, h, w) -> decoded target and reference (``_decode``)."""
        H, W = self.config.image_size
        z_ref = self.encode(torch.from_numpy(model_in))
        df = torch.from_numpy(delta).float().to(self.device)
        denoiser = self.denoiser if masks is None else PoseControlledDenoiser(
            self.denoiser, self.pose_adapter, torch.from_numpy(masks_to_model(masks, (H, W))).to(self.device, self.dtype))
        d = ddim_sample(denoiser, make_scheduler(self.config.diffusion), z_ref, df, noise.to(self.device), int(steps))
        return self._decode(z_ref, d)

    def generate_images(self, images, background, delta_force, **kwargs) -> np.ndarray:
        """Raw tactile images in, raw images out: uint8 (B, H, W, 3) with a (H, W, 3) no-contact background.

        Subtracts the background with the 127 offset, calls ``generate`` (same keyword options), adds it back.
        """
        from controltac_il.tactile import from_residual, to_residual

        images = _validate_residuals(images, "images")
        _check_aspect(images, self.config.image_size, "images")
        background = np.asarray(background)
        if background.dtype != np.uint8 or background.shape != images.shape[1:]:
            raise ValueError(f"background must be uint8 of shape {images.shape[1:]}, got {background.dtype} {background.shape}")
        residuals = np.stack([to_residual(im, background) for im in images])
        out = self.generate(residuals, delta_force, **kwargs)
        return np.stack([from_residual(r, background) for r in out])
