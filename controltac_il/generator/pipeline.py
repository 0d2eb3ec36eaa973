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

import numpy as np
import torch

from controltac_il.cli import RunFault
from controltac_il.generator.adapter import PoseAdapter, PoseControlledDenoiser, masks_to_model
from controltac_il.generator.autoencoder import TactileAutoencoder
from controltac_il.generator.batching import Footprint, free_bytes, rows_per_batch
from controltac_il.generator.checkpoint import ADAPTER_FILE, checkpoint_hash, load_adapter, load_checkpoint
from controltac_il.generator.config import DETAIL_GATE_SIGMA_PX, GeneratorConfig
from controltac_il.generator.dit import ForceDiT, force_condition
from controltac_il.generator.forces import TargetDecision
from controltac_il.generator.inputs import check_forces, check_options, check_residuals, decide_forces
from controltac_il.generator.masks import target_masks
from controltac_il.generator.resample import gaussian_blur, resize
from controltac_il.generator.sampler import ddim_sample, make_scheduler, seeded_noise
from controltac_il.generator.shipped import SHIPPED_ADAPTERS, locate_checkpoint
from controltac_il.tactile.residual import OFFSET
from controltac_il.training import parse_device

RESIDUAL_OFFSET = float(OFFSET)
# Every step of the path runs whole chunks of rows, the last padded by repeating its last row: CPU kernels round a
# 1-3-row product or convolution differently (the shipped DiT's conditioning, a small autoencoder's convolutions),
# and a GPU picks its kernels by shape, so a sample's bytes would depend on how many batch-mates it had. On the CPU
# a chunk is GENERATION_CHUNK rows (online mode, one frame a call, pays 4 rows' compute; tests/test_gen_api.py,
# tests/test_aug_lerobot.py pin the equality; benchmarks/generation_chunk.py sets it here to measure its cost); on
# an accelerator ACCELERATOR_CHUNK rows, enough to fill it at the GelSight Mini's 240×320.
GENERATION_CHUNK = 4
ACCELERATOR_CHUNK = 64


def chunk_rows(device: torch.device) -> int:
    """Rows per step of the path on ``device``: ``GENERATION_CHUNK`` on the CPU, ``ACCELERATOR_CHUNK`` elsewhere."""
    return GENERATION_CHUNK if device.type == "cpu" else ACCELERATOR_CHUNK


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


class ForceGenerator:
    """Force-control generator (autoencoder + ΔF-conditioned DiT + DDIM), with the optional stage-2 pose adapter
    (``pose_adapter``; ``load_pose_adapter``) that moves the contact to a target pose given as a contact mask.

    Every step runs as torch ops on ``device``; the resizes and the detail gate's blur (``resample``) run OpenCV's
    kernels on the CPU and index-select taps elsewhere; ``resample_taps=True`` runs the taps on the CPU too (the
    accelerator's path, checked on a CPU)."""

    def __init__(self, config: GeneratorConfig, autoencoder: TactileAutoencoder, denoiser: ForceDiT,
                 device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32, checkpoint_hash: str = "untracked",
                 pose_adapter: PoseAdapter | None = None, resample_taps: bool | None = None):
        if dtype not in (torch.float32, torch.bfloat16, torch.float16):
            raise ValueError(f"dtype must be torch.float32, torch.bfloat16 or torch.float16, got {dtype}")
        self.config = config
        self.device = parse_device(device)
        self.dtype = dtype
        self.autoencoder = autoencoder.to(self.device, dtype).eval()
        self.denoiser = denoiser.to(self.device, dtype).eval()
        self.checkpoint_hash = checkpoint_hash
        if resample_taps is False and self.device.type != "cpu":
            raise ValueError(f"resample_taps=False runs OpenCV, on the CPU only; this generator is on {self.device}")
        self.resample_taps = resample_taps
        self._footprints: dict[tuple[int, int], Footprint] = {}
        self.pose_adapter, self.pose_adapter_hash = None, None
        if pose_adapter is not None:
            self._check_adapter(pose_adapter.config, "the pose adapter")
            self.pose_adapter, self.pose_adapter_hash = pose_adapter.to(self.device, dtype).eval(), "untracked"
        c = config.autoencoder.latent_channels
        self._latent_scale = torch.tensor(config.latent_scale, device=self.device).view(1, c, 1, 1)
        self._delta_scale = torch.tensor(config.delta_scale, device=self.device).view(1, c, 1, 1)

    @classmethod
    def from_pretrained(cls, path: str | Path | None = None, device: str | torch.device = "cpu",
                        dtype: torch.dtype = torch.float32, pose_adapter: str | Path | None = None,
                        resample_taps: bool | None = None) -> "ForceGenerator":
        """Load a checkpoint folder, or a shipped preset: ``None`` or ``"default"``, ``"fast"`` (faster, twice the
        error) or ``"quality"`` (a 9.9 M-parameter DiT: the lowest error, slower); docs/generator.md has the frontier.
        ``pose_adapter``: also load a stage-2 adapter (a folder, or ``"pose"``, shipped for the default);
        ``resample_taps``: as the constructor."""
        path = locate_checkpoint(path)
        config, ae, dit = load_checkpoint(path)
        gen = cls(config, ae, dit, device=device, dtype=dtype, checkpoint_hash=checkpoint_hash(path),
                  resample_taps=resample_taps)
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
        not (every step runs whole chunks, ``chunk_rows``). A ForceAugment cache records it."""
        threads = torch.get_num_threads() if self.device.type == "cpu" else None
        return {"device": self.device.type, "dtype": str(self.dtype).removeprefix("torch."), "intra_op_threads": threads}

    # -- public API ----------------------------------------------------------------------------
    def generate(self, reference_residuals, delta_force, steps: int | None = None, seed: int | Sequence[int] = 0,
                 batch_size: int | str = 32, reference_force=None, out_of_range: str = "clamp", mask=None,
                 object_mask=None, transform=None) -> np.ndarray:
        """Residuals at the target force: uint8 (B, H, W, 3), same size as the input.

        reference_residuals: uint8 (B, H, W, 3) residual images (``to_residual``); any H, W (resized to
            the model's size and back). delta_force: (B, 3) [ΔFx, ΔFy, ΔFz] N = F_target - F_reference.
        steps: DDIM steps (>= 1), default ``config.default_steps``. seed: one int (every sample uses the
            same noise, so a sample's output never depends on its batch-mates) or B ints (one per sample).
        batch_size: samples moved to the device together, rounded up to whole chunks (``chunk_rows``), each
            step running one chunk at a time (memory only: a sample's bytes depend neither on it nor on its
            batch-mates; they do, rarely, on torch's thread count: ``numerics``); "auto": the largest batch that
            fits in the device's free memory (``batching``); an int batch that does not fit is refused (ValueError).
        reference_force: (B, 3) N, required by a checkpoint conditioned on it (``dit.reference_force``),
            optional otherwise; with it, targets outside the validated range
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
                    seed: int | Sequence[int] = 0, batch_size: int | str = 32, out_of_range: str = "clamp",
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

    def condition_reference(self, reference_force):
        """``reference_force`` (B, 3) N where this generator is conditioned on it (``dit.reference_force``), else
        None: for callers that hold the reference's force but want the range decision of a ΔF request alone."""
        return reference_force if self.config.dit.reference_force else None

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
        if delta is None and target is None:
            raise ValueError("delta_force (B, 3) N, or a target_force (B, 3) N with its reference_force, is required")
        steps, seeds = check_options(steps, seed, batch_size, n, self.config.default_steps,
                                     self.config.diffusion.num_train_timesteps)
        masks = target_masks(n, ref.shape[1:3], mask, object_mask, transform)
        if masks is not None and self.pose_adapter is None:
            raise ValueError("a target-pose mask needs the stage-2 pose adapter: "
                             "ForceGenerator.from_pretrained(pose_adapter='pose') or gen.load_pose_adapter()")
        decision, delta = decide_forces(out_of_range, reference_force, delta, target, reference_out_of_range,
                                        stacklevel=3)
        condition = force_condition(delta, reference_force, self.config.dit)
        return Generation(self._sample_rows(ref, condition, seeds, steps, batch_size, decision.generated, masks),
                          decision)

    def _sample_rows(self, ref: np.ndarray, delta: np.ndarray, seeds: list[int], steps: int, batch_size: int,
                     generated: np.ndarray, masks: np.ndarray | None) -> np.ndarray:
        """Residuals uint8 (B, H, W, 3): the rows ``generated`` (bool (B,)) selects sampled, the others ``ref``
        unchanged. Those rows are padded to whole chunks (``chunk_rows``) by repeating the last one and moved to
        the device ``batch_size`` (rounded up to whole chunks) at a time, so a row's bytes never depend on the
        others."""
        out, kept = ref.copy(), np.flatnonzero(generated)
        if len(kept) == 0:
            return out
        chunk = chunk_rows(self.device)
        rows = np.concatenate([kept, np.repeat(kept[-1:], -len(kept) % chunk)])
        lh, lw = self.config.autoencoder.latent_size
        noise = seeded_noise([seeds[i] for i in rows], (self.config.autoencoder.latent_channels, lh, lw))
        scheduler = make_scheduler(self.config.diffusion)
        step = rows_per_batch(batch_size, self.footprint(ref.shape[1:3]), free_bytes(self.device), chunk, len(rows))
        sampled = []
        for s in range(0, len(rows), step):
            b = rows[s:s + step]
            sampled.append(self._sample_batch(ref[b], delta[b], noise[s:s + step], steps, scheduler,
                                              None if masks is None else masks[b]))
        out[kept] = np.concatenate(sampled)[:len(kept)]
        return out

    def footprint(self, hw: tuple[int, int]) -> Footprint:
        """Bytes a batch of frames (H, W) = ``hw`` takes on the device (``batching``): on CUDA measured once per
        size, the allocator's peak over a one- and a two-chunk batch (which resets CUDA's peak statistics); elsewhere
        counted from its arrays (uint8 inputs and outputs and the noise per row; a chunk's float images, eight per
        row, fixed)."""
        hw = tuple(int(v) for v in hw)
        if hw not in self._footprints:
            chunk, image = chunk_rows(self.device), hw[0] * hw[1] * 3
            lh, lw = self.config.autoencoder.latent_size
            noise = 4 * self.config.autoencoder.latent_channels * lh * lw
            self._footprints[hw] = (self._measured_footprint(hw) if self.device.type == "cuda"
                                    else Footprint(chunk * 8 * 4 * image, 2 * image + noise))
        return self._footprints[hw]

    def _measured_footprint(self, hw: tuple[int, int]) -> Footprint:
        """``footprint`` on CUDA: peak bytes allocated by a batch of one and of two chunks of blank frames."""
        chunk = chunk_rows(self.device)
        lh, lw = self.config.autoencoder.latent_size
        ref = np.full((2 * chunk, *hw, 3), 127, np.uint8)
        noise = torch.zeros(2 * chunk, self.config.autoencoder.latent_channels, lh, lw)
        peaks = []
        for rows in (chunk, 2 * chunk):
            torch.cuda.synchronize(self.device)
            base = torch.cuda.memory_allocated(self.device)
            torch.cuda.reset_peak_memory_stats(self.device)
            self._sample_batch(ref[:rows], force_condition(np.zeros((rows, 3)), np.zeros((rows, 3)), self.config.dit),
                               noise[:rows], 1,
                               make_scheduler(self.config.diffusion), None)
            peaks.append(torch.cuda.max_memory_allocated(self.device) - base)
        per_row = max((peaks[1] - peaks[0]) // chunk, 2 * hw[0] * hw[1] * 3)
        return Footprint(max(peaks[0] - chunk * per_row, 0), per_row)

    def _to_device(self, a) -> torch.Tensor:
        """An array on the generator's device; to a GPU through pinned host memory, without waiting for the copy."""
        t = torch.as_tensor(a)
        if self.device.type == "cpu":
            return t
        return t.pin_memory().to(self.device, non_blocking=True)

    @torch.no_grad()
    def _sample_batch(self, ref: np.ndarray, delta: np.ndarray, noise: torch.Tensor, steps: int, scheduler,
                      masks: np.ndarray | None) -> np.ndarray:
        """One batch of whole chunks, on the device: reference residuals uint8 (b, H_in, W_in, 3), the force
        condition (b, 3 or 6) N (``force_condition``), seeded noise (b, C, h, w), target-pose masks bool (b, H_in,
        W_in) or None -> residuals uint8 (b, H_in, W_in, 3). Its inputs go to the device at once, its chunks are
        queued, its output comes back at once; NonFiniteOutput rather than a NaN turned into a black pixel."""
        chunk = chunk_rows(self.device)
        ref_d, delta_d = self._to_device(ref), self._to_device(np.asarray(delta, np.float32))
        noise_d = self._to_device(noise)
        outs, worst = [], torch.zeros((), device=self.device)
        for c in range(0, len(ref), chunk):
            rows = slice(c, c + chunk)
            y = self._sample(ref_d[rows], delta_d[rows], noise_d[rows], steps, scheduler,
                             None if masks is None else masks[rows])
            worst = torch.maximum(worst, y.abs().amax())  # NaN and inf carry through max; one check a batch
            outs.append(y.round().clamp_(0, 255).to(torch.uint8))
        out = torch.cat(outs)
        out = out if self.device.type == "cpu" else out.to("cpu", non_blocking=True)
        if not torch.isfinite(worst):  # waits for the device: the output's copy is complete after it
            dtype = str(self.dtype).removeprefix("torch.")
            raise NonFiniteOutput(f"the generator's output holds NaN or inf values ({dtype} on {self.device}); "
                                  "nothing was returned: check the checkpoint, or run in float32")
        return out.numpy()

    def _sample(self, ref: torch.Tensor, delta: torch.Tensor, noise: torch.Tensor, steps: int, scheduler,
                masks: np.ndarray | None) -> torch.Tensor:
        """The sampling loop on one chunk, every step on the device: reference residuals uint8 (c, H_in, W_in, 3),
        the force condition (c, 3 or 6) N, noise (c, C, h, w), masks bool (c, H_in, W_in) or None -> output grey
        levels float32 (c, H_in, W_in, 3), not yet rounded. One shape per chunk whatever the batch: the same
        kernels."""
        size_in = tuple(ref.shape[1:3])
        # 1. latent: the reference residual at the model's size (area resize), encoded: z_ref (c, C, h, w)
        z_ref = self.encode(resize(ref, self.config.image_size, "area", self.resample_taps))
        # 2. DDIM over the normalised latent delta Δz from the seeded noise, conditioned on (z_ref, ΔF[, mask])
        dz = ddim_sample(self._denoiser(masks), scheduler, z_ref, delta.float(), noise, steps)
        # 3. decode z_ref + Δz (and z_ref alone, when anchoring): float (c, h, w, 3), grey levels about 0
        target, recon = self._decode(z_ref, dz)
        # 4. resize to the input's size (the detail gate weighs at the model's)
        keep = None if recon is None else self._detail_weight(target, recon)
        target, recon, keep = (None if x is None else resize(x, size_in, "linear", self.resample_taps)
                               for x in (target, recon, keep))
        # 5. detail anchoring: + 127, plus the reference's detail its reconstruction misses, gated
        y = target + RESIDUAL_OFFSET
        return y if recon is None else y + keep * (ref.float() - RESIDUAL_OFFSET - recon)

    # -- model steps ---------------------------------------------------------------------------
    @torch.no_grad()
    def encode(self, residuals: torch.Tensor) -> torch.Tensor:
        """uint8 (B, H, W, 3) at the model size -> normalised reference latent (B, C, h, w)."""
        x = residual_to_unit(residuals.to(self.device)).to(self.dtype)
        return (self.autoencoder.encode(x).float() / self._latent_scale).to(self.dtype)

    def _denoiser(self, masks: np.ndarray | None):
        """The stage-1 denoiser, or with target-pose masks bool (c, H_in, W_in) the pose-controlled one."""
        if masks is None:
            return self.denoiser
        m = self._to_device(masks_to_model(masks, self.config.image_size)).to(self.dtype)
        return PoseControlledDenoiser(self.denoiser, self.pose_adapter, m)

    def _decode(self, z_ref_n: torch.Tensor, delta_n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Decoded target and (when anchoring) decoded reference, grey levels about 0, float32 (c, h, w, 3)."""
        def decode(z):
            return self.autoencoder.decode(z.to(self.dtype)).float().permute(0, 2, 3, 1) * 128.0
        target = decode(z_ref_n.float() * self._latent_scale + delta_n.float() * self._delta_scale)
        if not self.config.anchor_to_reference:
            return target, None
        return target, decode(z_ref_n.float() * self._latent_scale)

    def _detail_weight(self, target: torch.Tensor, recon: torch.Tensor) -> torch.Tensor:
        """Share of the reference's detail to keep, float32 (c, h, w, 1) in [0, 1] (GeneratorConfig.detail_gate)."""
        g = self.config.detail_gate
        if g == 0:
            return torch.ones_like(target[..., :1])
        def magnitude(x):
            a = x.abs()
            return gaussian_blur((a[..., 0] + a[..., 1] + a[..., 2]) / 3, DETAIL_GATE_SIGMA_PX,
                                 self.resample_taps)  # blur of the channel mean
        return ((magnitude(target) + g) / (magnitude(recon) + g)).clamp(0.0, 1.0)[..., None]
