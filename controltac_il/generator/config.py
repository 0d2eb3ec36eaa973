"""Configuration of the stage-1 force-control generator (autoencoder, DiT, sampler): pydantic dataclasses.

Every field is validated at construction (pydantic; errors are ValueErrors naming the field);
``to_dict`` / ``from_dict`` round-trip through JSON and refuse unknown fields.
"""

from __future__ import annotations

from dataclasses import field
from typing import Annotated, Literal

from pydantic import Field, model_validator
from pydantic.dataclasses import dataclass

from controltac_il.config import JsonConfig, PosInt, Positive, STRICT, one_line_errors
from controltac_il.generator.forces import VALIDATED_RANGE

# Validated force range of the paper, owned by ``controltac_il.generator.forces`` (these are its aliases).
FZ_RANGE = VALIDATED_RANGE.fz
SHEAR_MAX = VALIDATED_RANGE.shear_max
DETAIL_GATE_SIGMA_PX = 2.0  # smoothing of the contact magnitudes that gate the reference detail



@one_line_errors
@dataclass(config=STRICT)
class AutoencoderConfig(JsonConfig):
    """Compact deep-compression-style autoencoder for tactile residuals.

    image_size: (H, W) pixels of the residual it encodes; both divisible by 2**len(channels).
    channels: width of each down stage; every stage halves H and W (space-to-channel + 1x1 conv),
        so the spatial compression factor is 2**len(channels) (f8 for three stages).
    blocks_per_stage: residual blocks (conv3x3-SiLU-conv3x3) after each resolution change.
    stem_channels: width of the full-resolution stem convolution.
    latent_channels: channels of the latent map (H/f, W/f, latent_channels).
    """

    image_size: tuple[PosInt, PosInt] = (128, 160)
    channels: Annotated[tuple[PosInt, ...], Field(min_length=1)] = (16, 48, 96)
    blocks_per_stage: PosInt = 1
    stem_channels: PosInt = 12
    latent_channels: PosInt = 8

    @model_validator(mode="after")
    def _divisible(self):
        for i, v in enumerate(self.image_size):
            if v % self.factor:
                raise ValueError(f"image_size[{i}]={v} must be divisible by the compression factor {self.factor}")
        return self

    @property
    def factor(self) -> int:
        """Spatial compression factor f (image H / latent H)."""
        return 2 ** len(self.channels)

    @property
    def latent_size(self) -> tuple[int, int]:
        return (self.image_size[0] // self.factor, self.image_size[1] // self.factor)


@one_line_errors
@dataclass(config=STRICT)
class DiTConfig(JsonConfig):
    """Diffusion transformer denoiser (DiT style, adaLN-Zero), conditioned on timestep and ΔF.

    in_channels: channels of the noisy latent; the reference latent is concatenated, so the
        patch embedder sees 2 * in_channels.
    patch_size: latent pixels per token side.
    hidden_size, depth, num_heads, mlp_ratio: transformer width, blocks, attention heads, MLP expansion
        (hidden_size / num_heads must be an even int).
    force_scale: ΔF (N) is divided by this per component [Fx, Fy, Fz] before the ΔF embedder MLP.
    conv_head_width: channels of the local refinement head (three 3x3 convolutions at latent
        resolution on [DiT output, reference latent, noisy latent], last one zero-initialised, added to
        the DiT output; restores detail finer than a patch). 0 = no head (the plain DiT).
    reference_force: also conditioned on the reference's own force F_ref (N, scaled by ``force_scale``), through
        a second embedder whose last layer starts at zero: where on its force-response curve the contact starts.
        Its force condition is then (B, 6) [ΔF, F_ref] (``dit.force_condition``).
    """

    in_channels: PosInt = 8
    patch_size: PosInt = 2
    hidden_size: PosInt = 128
    depth: PosInt = 4
    num_heads: PosInt = 4
    mlp_ratio: Positive = 4.0
    force_scale: tuple[Positive, Positive, Positive] = (2.0, 2.0, 9.0)
    conv_head_width: Annotated[int, Field(ge=0)] = 0
    reference_force: bool = False

    @model_validator(mode="after")
    def _heads(self):
        if self.hidden_size % self.num_heads or (self.hidden_size // self.num_heads) % 2:
            raise ValueError(f"hidden_size={self.hidden_size} / num_heads={self.num_heads} must be an even int")
        return self

    @classmethod
    def small(cls, in_channels: int = 8, patch_size: int = 2, conv_head_width: int = 0) -> "DiTConfig":
        """DiT-S (this project's default teacher): 128 wide, 4 blocks."""
        return cls(in_channels=in_channels, patch_size=patch_size, hidden_size=128, depth=4, num_heads=4,
                   conv_head_width=conv_head_width)

    @classmethod
    def tiny(cls, in_channels: int = 8, patch_size: int = 2, conv_head_width: int = 0) -> "DiTConfig":
        """DiT-T (faster variant): 96 wide, 2 blocks."""
        return cls(in_channels=in_channels, patch_size=patch_size, hidden_size=96, depth=2, num_heads=4,
                   conv_head_width=conv_head_width)

    @classmethod
    def base(cls, in_channels: int = 8, patch_size: int = 2, conv_head_width: int = 0) -> "DiTConfig":
        """DiT-B: 256 wide, 8 blocks (too slow for the 2-core CPU target; for GPUs)."""
        return cls(in_channels=in_channels, patch_size=patch_size, hidden_size=256, depth=8, num_heads=8,
                   conv_head_width=conv_head_width)


@one_line_errors
@dataclass(config=STRICT)
class DiffusionConfig(JsonConfig):
    """Noise schedule and sampler defaults (diffusers' DDIMScheduler).

    num_train_timesteps: length of the training noise schedule.
    beta_schedule: diffusers beta schedule name.
    prediction_type: "epsilon" (the paper: the DiT predicts the noise) or "sample" (predicts the
        clean latent ΔF-delta directly; better at 1-2 steps, used by the faster variant).
    default_steps: DDIM steps used when ``generate(steps=None)`` (at most num_train_timesteps).
    """

    num_train_timesteps: PosInt = 1000
    beta_schedule: Literal["scaled_linear", "linear", "squaredcos_cap_v2"] = "scaled_linear"
    prediction_type: Literal["epsilon", "sample"] = "epsilon"
    default_steps: PosInt = 10

    @model_validator(mode="after")
    def _steps(self):
        if self.default_steps > self.num_train_timesteps:
            raise ValueError("default_steps must be <= num_train_timesteps")
        return self


@one_line_errors
@dataclass(config=STRICT)
class GeneratorConfig(JsonConfig):
    """Everything needed to rebuild a trained generator (saved as ``config.json`` beside the weights).

    autoencoder, dit, diffusion: the sub-configs above.
    latent_scale: per-channel std of reference latents; the DiT sees ``z_ref / latent_scale``.
    delta_scale: per-channel std of latent differences ``z_target - z_ref`` over training pairs; the
        diffusion runs on ``(z_target - z_ref) / delta_scale`` (the latent the reference must move by).
        Both: one positive number per latent channel; empty = all 1.
    anchor_to_reference: if True the output is ``reference + decode(z_ref + Δz) - decode(z_ref)``,
        keeping the reference's fine detail where the force change does not move it.
    detail_gate: with anchoring, > 0 keeps the reference's detail (``reference - decode(z_ref)``, what
        the autoencoder misses) only as far as the target keeps the reference's contact: per-pixel
        weight ``clip((m_target + g) / (m_ref + g), 0, 1)``, m = decoded residual magnitude (grey levels,
        Gaussian-smoothed, σ = ``DETAIL_GATE_SIGMA_PX`` at the model size), g = this value (grey levels).
        Without it a force decrease leaves a ghost of the reference contact; g keeps the weight near
        1 on the bare gel, so the reference's sensor noise is kept. 0 = plain anchoring.
    """

    autoencoder: AutoencoderConfig = field(default_factory=AutoencoderConfig)
    dit: DiTConfig = field(default_factory=DiTConfig)
    diffusion: DiffusionConfig = field(default_factory=DiffusionConfig)
    latent_scale: tuple[Positive, ...] = ()
    delta_scale: tuple[Positive, ...] = ()
    anchor_to_reference: Annotated[bool, Field(strict=True)] = False
    detail_gate: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.0

    @model_validator(mode="after")
    def _consistent(self):
        c = self.autoencoder.latent_channels
        if self.dit.in_channels != c:
            raise ValueError(f"dit.in_channels={self.dit.in_channels} must equal autoencoder.latent_channels={c}")
        lh, lw = self.autoencoder.latent_size
        if lh % self.dit.patch_size or lw % self.dit.patch_size:
            raise ValueError(f"latent size {(lh, lw)} must be divisible by dit.patch_size={self.dit.patch_size}")
        for name in ("latent_scale", "delta_scale"):
            v = getattr(self, name) or (1.0,) * c
            if len(v) != c:
                raise ValueError(f"{name} must be {c} positive numbers (one per latent channel), got {v!r}")
            setattr(self, name, v)
        if self.detail_gate > 0 and not self.anchor_to_reference:
            raise ValueError("detail_gate > 0 needs anchor_to_reference=True (it gates the anchored reference detail)")
        return self

    @property
    def image_size(self) -> tuple[int, int]:
        return self.autoencoder.image_size

    @property
    def default_steps(self) -> int:
        return self.diffusion.default_steps


@one_line_errors
@dataclass(config=STRICT)
class PoseAdapterConfig(JsonConfig):
    """Stage-2 pose-control adapter over a frozen stage-1 generator (ControlNet-style), saved as its config.json.

    base: the stage-1 generator's config (the adapter's shapes follow it).
    base_hash: ``checkpoint_hash`` of the stage-1 checkpoint it was trained on ("" = not recorded);
        ``ForceGenerator.load_pose_adapter`` refuses an adapter whose base hash is not the generator's.
    mask_channels: channels of the mask encoder (space-to-depth of the contact mask to the latent size, then
        two 3x3 convolutions).
    head_width: channels of the zero-initialised output convolution on [denoiser output, encoded mask].
    alignment_px, alignment_deg: the training masks' alignment noise (uniform in ±these, pixels of the
        training images and degrees), as the paper's ±3 px, ±1°.
    """

    base: GeneratorConfig = field(default_factory=GeneratorConfig)
    base_hash: str = ""
    mask_channels: PosInt = 32
    head_width: PosInt = 48
    alignment_px: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 3.0
    alignment_deg: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 1.0
