"""``ForceGenerator``: reference tactile residual + ΔF -> residual at the target force (inference API).

    gen = ForceGenerator.from_pretrained()                 # shipped default checkpoint
    out = gen.generate(reference_residuals, delta_force)   # uint8 (B, H, W, 3) in and out
    res = gen.generate_at(residuals, reference_force, target_force)  # res.residuals, res.decision
    imgs = gen.generate_images(images, background, delta_force)
    gen = ForceGenerator.from_pretrained(pose_adapter="pose")  # with stage 2, the pose adapter
    out = gen.generate(reference_residuals, delta_force, object_mask=masks, transform=(dx_px, dy_px, dtheta))

``generate`` (ΔF) and ``generate_at`` (target forces, with what was done per sample) are two questions over one
path, ``ForceGenerator._generate``: its inputs are checked (``inputs``; stage-2 masks in ``masks``), its range
decision taken once (``inputs.decide_forces`` over ``forces.decide_targets``: clamp, skip or refuse a target outside
``forces.VALIDATED_RANGE``; a reference force outside it is refused, or its sample skipped), and the rows it
generates run through the sampling loop ``ForceGenerator._sample``.

Sampling: residual -> [-1, 1] -> encoder -> z_ref; DDIM samples the normalised latent delta
Δz = (z_target - z_ref) / delta_scale conditioned on (z_ref, ΔF); decode(z_ref + Δz) -> residual.
"""

from __future__ import annotations

from dataclasses import dataclass
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
from controltac_il.generator.forces import TargetDecision
from controltac_il.generator.inputs import check_forces, check_options, check_residuals, decide_forces
from controltac_il.generator.masks import target_masks
from controltac_il.generator.sampler import ddim_sample, make_scheduler, seeded_noise
from controltac_il.generator.shipped import SHIPPED_ADAPTERS, locate_checkpoint
from controltac_il.tactile.residual import OFFSET

RESIDUAL_OFFSET = float(OFFSET)
# Every forward pass runs whole chunks of this many rows, the last padded by repeating its last row: CPU kernels
# round a 1-3-row product or convolution differently (the shipped DiT's conditioning, a small autoencoder's
# convolutions), so a sample's bytes would depend on how many batch-mates it had. Costs online mode (one frame a
# call) the chunk's compute (tests/test_gen_api.py, tests/test_aug_lerobot.py pin the equality). It stays beside the
# loop that chunks by it (benchmarks/generation_chunk.py sets it here to measure its cost).
GENERATION_CHUNK = 4


def residual_to_unit(residual: torch.Tensor) -> torch.Tensor:
    """uint8 residual (B, H, W, 3) -> float (B, 3, H, W), 127 -> 0, scale 1/128."""
    return (residual.permute(0, 3, 1, 2).float() - RESIDUAL_OFFSET) / 128.0


class NonFiniteOutput(RunFault):
    """The generator's output held NaN or inf (a checkpoint trained into NaN, or beyond its dtype's range)."""


@dataclass(frozen=True)
class Generation:
    """What ``generate_at`` returns: the residuals and what was done with each requested target.

    residuals: uint8 (B, H, W, 3) at the references' size; a skipped sample's is its reference residual, unchanged.
    decision: ``forces.TargetDecision``, per sample: requested and used target force (B, 3) N, clamped, skipped
        and reference_outside bool (B,).
    """

    residuals: np.ndarray
    decision: TargetDecision


def _resize_each(images: np.ndarray | None, hw: tuple[int, int], interpolation: int = cv2.INTER_LINEAR):
    """Each image of (B, H, W[, C]) resized to hw = (H', W'); None, and images already of that size, as they are.
    A trailing channel of 1 is resized as a plain (H, W) image and kept."""
    if images is None or images.shape[1:3] == tuple(hw):
        return images
    one = images.ndim == 4 and images.shape[-1] == 1
    out = np.stack([cv2.resize(x, hw[::-1], interpolation=interpolation) for x in (images[..., 0] if one else images)])
    return out[..., None] if one else out


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
            to ΔF beyond the range's span. Clamps are warned about (UserWarning with their count). A reference
            force outside the range is refused (ValueError) unless out_of_range="skip", which returns that
            sample's reference unchanged. ``generate_at`` takes target forces and says what it did per sample.
        Images whose aspect ratio differs from the model's by more than ``inputs.MAX_ASPECT_CHANGE`` are refused.
        Stage 2 (needs ``pose_adapter``): ``mask``, the contact mask at the target pose, bool or 0/1 (H, W) for
            all or (B, H, W), at the references' size; or ``object_mask`` (the contact at the reference pose, e.g.
            ``tactile.contact_mask`` of the reference) with ``transform`` (3,) or (B, 3) = (dx_px, dy_px, dtheta):
            rotate by dtheta rad counter-clockwise as displayed about the mask's centroid, then shift dx_px
            columns right and dy_px rows down (``tactile.pose``). The output shows the contact at that pose and
            the target force. Empty masks, masks of another size and moves that leave nothing on the pad are
            refused (ValueError). Without a mask: exactly stage 1.
        """
        return self._generate(reference_residuals, delta_force=delta_force, reference_force=reference_force,
                              out_of_range=out_of_range, steps=steps, seed=seed, batch_size=batch_size, mask=mask,
                              object_mask=object_mask, transform=transform).residuals

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
        return self._generate(reference_residuals, reference_force=reference_force, target_force=target_force,
                              out_of_range=out_of_range, reference_out_of_range=reference_out_of_range, steps=steps,
                              seed=seed, batch_size=batch_size, mask=mask, object_mask=object_mask,
                              transform=transform)

    def resolve_targets(self, target_force, out_of_range: str = "clamp", reference_force=None,
                        reference_out_of_range: str | None = None) -> TargetDecision:
        """What ``generate_at`` would decide for these target forces (B, 3) N (and, when given, these reference
        forces), without generating."""
        n = np.shape(target_force)[0] if np.ndim(target_force) else -1
        ref_f = None if reference_force is None else check_forces(reference_force, n, "reference_force")
        return decide_forces(out_of_range, ref_f, target=check_forces(target_force, n, "target_force"),
                             reference_out_of_range=reference_out_of_range)[0]

    def generate_images(self, images, background, delta_force, **kwargs) -> np.ndarray:
        """Raw tactile images in, raw images out: uint8 (B, H, W, 3) with a (H, W, 3) no-contact background.

        Subtracts the background with the 127 offset, calls ``generate`` (same keyword options), adds it back.
        """
        from controltac_il.tactile import from_residual, to_residual

        images = check_residuals(images, "images", self.config.image_size)
        background = np.asarray(background)
        if background.dtype != np.uint8 or background.shape != images.shape[1:]:
            raise ValueError(f"background must be uint8 of shape {images.shape[1:]}, got {background.dtype} {background.shape}")
        residuals = np.stack([to_residual(im, background) for im in images])
        out = self.generate(residuals, delta_force, **kwargs)
        return np.stack([from_residual(r, background) for r in out])

    # -- the one generation path ---------------------------------------------------------------------
    def _generate(self, reference_residuals, *, reference_force=None, delta_force=None, target_force=None,
                  out_of_range: str = "clamp", reference_out_of_range: str | None = None, steps: int | None = None,
                  seed: int | Sequence[int] = 0, batch_size: int = 32, mask=None, object_mask=None,
                  transform=None) -> Generation:
        """Check the inputs, take the range decision once, sample the rows it keeps (``generate``'s arguments).

        A request is ``delta_force`` (B, 3) N, optionally with ``reference_force``, or ``target_force`` with
        ``reference_force`` (B, 3) N; ``inputs.decide_forces`` says what each becomes (and warns for ΔF)."""
        ref = check_residuals(reference_residuals, "reference_residuals", self.config.image_size)
        n = len(ref)
        delta = None if delta_force is None else check_forces(delta_force, n, "delta_force")
        if reference_force is not None or target_force is not None:  # a target needs its reference
            reference_force = check_forces(reference_force, n, "reference_force")
        target = None if target_force is None else check_forces(target_force, n, "target_force")
        steps, seeds = check_options(steps, seed, batch_size, n, self.config.default_steps,
                                     self.config.diffusion.num_train_timesteps)
        masks = target_masks(n, ref.shape[1:3], mask, object_mask, transform)
        if masks is not None and self.pose_adapter is None:
            raise ValueError("a target-pose mask needs the stage-2 pose adapter: "
                             "ForceGenerator.from_pretrained(pose_adapter='pose') or gen.load_pose_adapter()")
        decision, delta = decide_forces(out_of_range, reference_force, delta, target, reference_out_of_range,
                                        stacklevel=3)
        return Generation(self._sample_rows(ref, delta, seeds, steps, batch_size, decision.generated, masks),
                          decision)

    def _sample_rows(self, ref: np.ndarray, delta: np.ndarray, seeds: list[int], steps: int, batch_size: int,
                     generated: np.ndarray, masks: np.ndarray | None) -> np.ndarray:
        """Residuals uint8 (B, H, W, 3): the rows ``generated`` (bool (B,)) selects sampled (``_sample``), the others
        ``ref`` unchanged. Those rows are padded to whole ``GENERATION_CHUNK``s by repeating the last one and
        sampled ``batch_size`` (rounded up to whole chunks) at a time, so a row's bytes never depend on the others."""
        out, kept = ref.copy(), np.flatnonzero(generated)
        if len(kept) == 0:
            return out
        rows = np.concatenate([kept, np.repeat(kept[-1:], -len(kept) % GENERATION_CHUNK)])
        lh, lw = self.config.autoencoder.latent_size
        noise = seeded_noise([seeds[i] for i in rows], (self.config.autoencoder.latent_channels, lh, lw))
        step = -(-batch_size // GENERATION_CHUNK) * GENERATION_CHUNK
        sampled = []
        for s in range(0, len(rows), step):
            b = rows[s:s + step]
            sampled.append(self._sample(ref[b], delta[b], noise[s:s + step], steps, None if masks is None else masks[b]))
        out[kept] = np.concatenate(sampled)[:len(kept)]
        return out

    @torch.no_grad()
    def _sample(self, ref: np.ndarray, delta: np.ndarray, noise: torch.Tensor, steps: int,
                masks: np.ndarray | None) -> np.ndarray:
        """The sampling loop on whole ``GENERATION_CHUNK``s of rows: reference residuals uint8 (b, H_in, W_in, 3),
        ΔF (b, 3) N, seeded noise (b, C, h, w), target-pose masks bool (b, H_in, W_in) or None -> residuals uint8
        (b, H_in, W_in, 3). The networks run one chunk at a time: one shape whatever b, so the same CPU kernels."""
        size_in = ref.shape[1:3]
        # 1. reference residual at the model's size (area resize)
        model_in = _resize_each(ref, self.config.image_size, cv2.INTER_AREA)
        decoded = []
        for c in range(0, len(ref), GENERATION_CHUNK):
            rows = slice(c, c + GENERATION_CHUNK)
            # 2. latent: the normalised reference latent z_ref (c, C, h, w)
            z_ref = self.encode(torch.from_numpy(model_in[rows]))
            # 3. DDIM over the normalised latent delta Δz from the seeded noise, conditioned on (z_ref, ΔF[, mask])
            df = torch.from_numpy(delta[rows]).float().to(self.device)
            dz = ddim_sample(self._denoiser(masks, rows), make_scheduler(self.config.diffusion), z_ref, df,
                             noise[rows].to(self.device), steps)
            # 4. decode z_ref + Δz (and z_ref alone, when anchoring): float (c, H, W, 3), grey levels about 0
            decoded.append(self._decode(z_ref, dz))
        target = np.concatenate([t for t, _ in decoded])
        recon = None if decoded[0][1] is None else np.concatenate([r for _, r in decoded])
        # 5. resize to the input's size (the detail gate weighs at the model's)
        keep = None if recon is None else self._detail_weight(target, recon)
        target, recon, keep = (_resize_each(x, size_in) for x in (target, recon, keep))
        # 6. detail anchoring: the reference's detail its reconstruction misses, gated; -> uint8
        return self._anchored(ref, target, recon, keep)

    # -- model steps ---------------------------------------------------------------------------
    @torch.no_grad()
    def encode(self, residuals: torch.Tensor) -> torch.Tensor:
        """uint8 (B, H, W, 3) at the model size -> normalised reference latent (B, C, h, w)."""
        x = residual_to_unit(residuals.to(self.device)).to(self.dtype)
        return (self.autoencoder.encode(x).float() / self._latent_scale).to(self.dtype)

    def _denoiser(self, masks: np.ndarray | None, rows: slice):
        """The stage-1 denoiser, or with target-pose masks bool (b, H_in, W_in) the pose-controlled one for ``rows``."""
        if masks is None:
            return self.denoiser
        m = torch.from_numpy(masks_to_model(masks[rows], self.config.image_size)).to(self.device, self.dtype)
        return PoseControlledDenoiser(self.denoiser, self.pose_adapter, m)

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

    def _anchored(self, ref: np.ndarray, target: np.ndarray, recon: np.ndarray | None,
                  keep: np.ndarray | None) -> np.ndarray:
        """uint8 (b, H, W, 3): decoded target + 127, plus (when anchoring) ``keep`` (b, H, W, 1) of the reference's
        detail (reference - its reconstruction); NonFiniteOutput rather than a NaN turned into a black pixel."""
        y = target + RESIDUAL_OFFSET
        if recon is not None:
            y = y + keep * (ref.astype(np.float32) - RESIDUAL_OFFSET - recon)
        bad = int(y.size - np.isfinite(y).sum())
        if bad:
            dtype = str(self.dtype).removeprefix("torch.")
            raise NonFiniteOutput(f"the generator's output holds {bad} NaN or inf values ({dtype} on {self.device}); "
                                  "nothing was returned: check the checkpoint, or run in float32")
        return np.clip(np.round(y), 0, 255).astype(np.uint8)
