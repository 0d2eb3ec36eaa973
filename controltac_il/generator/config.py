"""Configuration dataclasses of the stage-1 force-control generator (autoencoder, DiT, sampler).

Each config is a plain dataclass: ``to_dict`` / ``from_dict`` round-trip through JSON, ``__post_init__``
validates every field and names it in the error.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

# Validated force range of the paper: target Fz in [1, 10] N, |Fx|, |Fy| <= 1 N.
FZ_RANGE = (1.0, 10.0)
SHEAR_MAX = 1.0
DETAIL_GATE_SIGMA_PX = 2.0  # smoothing of the contact magnitudes that gate the reference detail


def _check_pos_int(name: str, value: Any) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
        raise ValueError(f"{name} must be a positive int, got {value!r}")


def _from_dict(cls, d: dict):
    if not isinstance(d, dict):
        raise ValueError(f"{cls.__name__}: expected a dict, got {type(d).__name__}")
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(d) - names
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown fields {sorted(unknown)}; expected a subset of {sorted(names)}")
    return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()})


@dataclass
class AutoencoderConfig:
    """Compact deep-compression-style autoencoder for tactile residuals.

    image_size: (H, W) pixels of the residual it encodes; both divisible by 2**len(channels).
    channels: width of each down stage; every stage halves H and W (space-to-channel + 1x1 conv),
        so the spatial compression factor is 2**len(channels) (f8 for three stages).
    blocks_per_stage: residual blocks (conv3x3-SiLU-conv3x3) after each resolution change.
    stem_channels: width of the full-resolution stem convolution.
    latent_channels: channels of the latent map (H/f, W/f, latent_channels).
    """

    image_size: tuple[int, int] = (128, 160)
    channels: tuple[int, ...] = (16, 48, 96)
    blocks_per_stage: int = 1
    stem_channels: int = 12
    latent_channels: int = 8

    def __post_init__(self):
        self.image_size = tuple(self.image_size)
        self.channels = tuple(self.channels)
        if len(self.image_size) != 2:
            raise ValueError(f"image_size must be (H, W), got {self.image_size!r}")
        f = self.factor if self.channels else 1
        for n, v in zip(("image_size[0]", "image_size[1]"), self.image_size):
            _check_pos_int(n, v)
            if v % f:
                raise ValueError(f"{n}={v} must be divisible by the compression factor {f}")
        if not self.channels:
            raise ValueError("channels must list at least one stage width")
        for i, c in enumerate(self.channels):
            _check_pos_int(f"channels[{i}]", c)
        _check_pos_int("blocks_per_stage", self.blocks_per_stage)
        _check_pos_int("stem_channels", self.stem_channels)
        _check_pos_int("latent_channels", self.latent_channels)

    @property
    def factor(self) -> int:
        """Spatial compression factor f (image H / latent H)."""
        return 2 ** len(self.channels)

    @property
    def latent_size(self) -> tuple[int, int]:
        return (self.image_size[0] // self.factor, self.image_size[1] // self.factor)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "AutoencoderConfig":
        return _from_dict(cls, d)


@dataclass
class DiTConfig:
    """Diffusion transformer denoiser (DiT style, adaLN-Zero), conditioned on timestep and ΔF.

    in_channels: channels of the noisy latent; the reference latent is concatenated, so the
        patch embedder sees 2 * in_channels.
    patch_size: latent pixels per token side.
    hidden_size, depth, num_heads, mlp_ratio: transformer width, blocks, attention heads, MLP expansion.
    force_scale: ΔF (N) is divided by this per component [Fx, Fy, Fz] before the ΔF embedder MLP.
    conv_head_width: channels of the local refinement head (three 3x3 convolutions at latent
        resolution on [DiT output, reference latent, noisy latent], last one zero-initialised, added to
        the DiT output; restores detail finer than a patch). 0 = no head (the plain DiT).
    """

    in_channels: int = 8
    patch_size: int = 2
    hidden_size: int = 128
    depth: int = 4
    num_heads: int = 4
    mlp_ratio: float = 4.0
    force_scale: tuple[float, float, float] = (2.0, 2.0, 9.0)
    conv_head_width: int = 0

    def __post_init__(self):
        self.force_scale = tuple(float(v) for v in self.force_scale)
        if not isinstance(self.conv_head_width, int) or isinstance(self.conv_head_width, bool) or self.conv_head_width < 0:
            raise ValueError(f"conv_head_width must be an int >= 0 (0 = no head), got {self.conv_head_width!r}")
        for n in ("in_channels", "patch_size", "hidden_size", "depth", "num_heads"):
            _check_pos_int(n, getattr(self, n))
        if self.hidden_size % self.num_heads:
            raise ValueError(f"hidden_size={self.hidden_size} must be divisible by num_heads={self.num_heads}")
        if (self.hidden_size // self.num_heads) % 2:
            raise ValueError("hidden_size / num_heads must be even")
        if not self.mlp_ratio > 0:
            raise ValueError(f"mlp_ratio must be > 0, got {self.mlp_ratio!r}")
        if len(self.force_scale) != 3 or any(not v > 0 for v in self.force_scale):
            raise ValueError(f"force_scale must be three positive numbers (N), got {self.force_scale!r}")

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

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "DiTConfig":
        return _from_dict(cls, d)


PREDICTION_TYPES = ("epsilon", "sample")
BETA_SCHEDULES = ("scaled_linear", "linear", "squaredcos_cap_v2")


@dataclass
class DiffusionConfig:
    """Noise schedule and sampler defaults (diffusers' DDIMScheduler).

    num_train_timesteps: length of the training noise schedule.
    beta_schedule: diffusers beta schedule name.
    prediction_type: "epsilon" (the paper: the DiT predicts the noise) or "sample" (predicts the
        clean latent ΔF-delta directly; better at 1-2 steps, used by the faster variant).
    default_steps: DDIM steps used when ``generate(steps=None)``.
    """

    num_train_timesteps: int = 1000
    beta_schedule: str = "scaled_linear"
    prediction_type: str = "epsilon"
    default_steps: int = 10

    def __post_init__(self):
        _check_pos_int("num_train_timesteps", self.num_train_timesteps)
        _check_pos_int("default_steps", self.default_steps)
        if self.beta_schedule not in BETA_SCHEDULES:
            raise ValueError(f"beta_schedule must be one of {BETA_SCHEDULES}, got {self.beta_schedule!r}")
        if self.prediction_type not in PREDICTION_TYPES:
            raise ValueError(f"prediction_type must be one of {PREDICTION_TYPES}, got {self.prediction_type!r}")
        if self.default_steps > self.num_train_timesteps:
            raise ValueError("default_steps must be <= num_train_timesteps")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "DiffusionConfig":
        return _from_dict(cls, d)


@dataclass
class GeneratorConfig:
    """Everything needed to rebuild a trained generator (saved as ``config.json`` beside the weights).

    autoencoder, dit, diffusion: the sub-configs above.
    latent_scale: per-channel std of reference latents; the DiT sees ``z_ref / latent_scale``.
    delta_scale: per-channel std of latent differences ``z_target - z_ref`` over training pairs; the
        diffusion runs on ``(z_target - z_ref) / delta_scale`` (the latent the reference must move by).
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
    latent_scale: tuple[float, ...] = ()
    delta_scale: tuple[float, ...] = ()
    anchor_to_reference: bool = False
    detail_gate: float = 0.0

    def __post_init__(self):
        if isinstance(self.autoencoder, dict):
            self.autoencoder = AutoencoderConfig.from_dict(self.autoencoder)
        if isinstance(self.dit, dict):
            self.dit = DiTConfig.from_dict(self.dit)
        if isinstance(self.diffusion, dict):
            self.diffusion = DiffusionConfig.from_dict(self.diffusion)
        c = self.autoencoder.latent_channels
        if self.dit.in_channels != c:
            raise ValueError(f"dit.in_channels={self.dit.in_channels} must equal autoencoder.latent_channels={c}")
        lh, lw = self.autoencoder.latent_size
        if lh % self.dit.patch_size or lw % self.dit.patch_size:
            raise ValueError(f"latent size {(lh, lw)} must be divisible by dit.patch_size={self.dit.patch_size}")
        for name in ("latent_scale", "delta_scale"):
            v = tuple(float(x) for x in getattr(self, name)) or (1.0,) * c
            if len(v) != c or any(not x > 0 for x in v):
                raise ValueError(f"{name} must be {c} positive numbers (one per latent channel), got {v!r}")
            setattr(self, name, v)
        if not isinstance(self.anchor_to_reference, bool):
            raise ValueError(f"anchor_to_reference must be a bool, got {self.anchor_to_reference!r}")
        if isinstance(self.detail_gate, bool) or not isinstance(self.detail_gate, (int, float)) or not self.detail_gate >= 0:
            raise ValueError(f"detail_gate must be a number >= 0 (grey levels), got {self.detail_gate!r}")
        if self.detail_gate > 0 and not self.anchor_to_reference:
            raise ValueError("detail_gate > 0 needs anchor_to_reference=True (it gates the anchored reference detail)")

    @property
    def image_size(self) -> tuple[int, int]:
        return self.autoencoder.image_size

    @property
    def default_steps(self) -> int:
        return self.diffusion.default_steps

    def to_dict(self) -> dict:
        return {
            "autoencoder": self.autoencoder.to_dict(),
            "dit": self.dit.to_dict(),
            "diffusion": self.diffusion.to_dict(),
            "latent_scale": list(self.latent_scale),
            "delta_scale": list(self.delta_scale),
            "anchor_to_reference": self.anchor_to_reference,
            "detail_gate": self.detail_gate,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "GeneratorConfig":
        return _from_dict(cls, d)
