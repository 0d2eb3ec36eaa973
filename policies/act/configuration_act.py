"""ACT configuration: one dataclass, two presets (``gpu`` as in the paper, ``cpu`` for 2 cores).

Defaults follow ACT (Zhao et al. 2023) and the ControlTac imitation-learning setting: action chunk
N_a = 20, KL weight 10, one decoder layer (what the original implementation effectively uses),
temporal-ensembling weights exp(-0.01 i).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

BACKBONES = ("resnet18", "small_cnn")


def _size_pair(value, name: str) -> tuple[int, int]:
    try:
        h, w = (int(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"ACTConfig.{name} must be a pair (height, width) of positive ints, got {value!r}") from None
    if h <= 0 or w <= 0:
        raise ValueError(f"ACTConfig.{name} must be a pair (height, width) of positive ints, got {value!r}")
    return h, w


@dataclass
class ACTConfig:
    """Architecture and loss of the ACT policy (CVAE with a transformer encoder/decoder).

    Data layout (must match the episodes the policy is trained on and deployed with):
        camera_names: RGB cameras, e.g. ("third_view", "wrist"); each is one image stream.
        tactile_names: tactile sensors, e.g. ("left", "right"); each is one image stream, fed as the
            background-subtracted residual (image - background) / 255 in [-1, 1].
        state_dim: length D of the proprioception vector ``observation.qpos``.
        action_dim: length A of one action (scene: [x, y, z, yaw, gripper] -> 5).
        chunk_size: N_a, actions predicted per inference (paper: 20 at 10 Hz).

    Image streams:
        backbone: "resnet18" (ResNet-18 written in this repo, stride 32) or "small_cnn" (4 strided
            3x3 convs, stride 16). Cameras share one backbone, tactile sensors another.
        camera_size / tactile_size: (H, W) in pixels every camera / tactile frame is resized to
            before its backbone.

    Transformer:
        dim_model: token width; n_heads: attention heads; dim_feedforward: MLP width;
        n_encoder_layers / n_decoder_layers: main transformer depth (decoder: 1, as in ACT);
        n_vae_encoder_layers: depth of the CVAE encoder over [CLS, qpos, action chunk];
        latent_dim: size of the CVAE style variable z (0-mean prior; z = 0 at inference);
        dropout: dropout in the transformer layers.

    Loss and optimisation:
        kl_weight: weight of KL(q(z|a, s) || N(0, I)) added to the masked L1 on actions (ACT: 10).
        lr / lr_backbone / weight_decay: AdamW learning rates (transformer, image backbones) and decay.
        temporal_ensemble_coeff: k in the ensembling weights exp(-k i), i = age of a prediction.
    """

    camera_names: tuple[str, ...] = ("third_view", "wrist")
    tactile_names: tuple[str, ...] = ("left", "right")
    state_dim: int = 5
    action_dim: int = 5
    chunk_size: int = 20
    backbone: str = "resnet18"
    camera_size: tuple[int, int] = (240, 320)
    tactile_size: tuple[int, int] = (240, 320)
    dim_model: int = 512
    n_heads: int = 8
    dim_feedforward: int = 3200
    n_encoder_layers: int = 4
    n_decoder_layers: int = 1
    n_vae_encoder_layers: int = 4
    latent_dim: int = 32
    dropout: float = 0.1
    kl_weight: float = 10.0
    lr: float = 1e-5
    lr_backbone: float = 1e-5
    weight_decay: float = 1e-4
    temporal_ensemble_coeff: float = 0.01
    preset: str = field(default="custom")

    def __post_init__(self) -> None:
        self.camera_names = tuple(self.camera_names)
        self.tactile_names = tuple(self.tactile_names)
        for name in ("camera_names", "tactile_names"):
            names = getattr(self, name)
            if any(not isinstance(n, str) or not n or "." in n or "/" in n for n in names):
                raise ValueError(f"ACTConfig.{name} must be non-empty names without '.' or '/', got {names!r}")
            if len(set(names)) != len(names):
                raise ValueError(f"ACTConfig.{name} has duplicates: {names!r}")
        if not self.camera_names and not self.tactile_names:
            raise ValueError("ACTConfig needs at least one image stream (camera_names or tactile_names)")
        for name in ("state_dim", "action_dim", "chunk_size", "dim_model", "n_heads", "dim_feedforward",
                     "n_encoder_layers", "n_decoder_layers", "n_vae_encoder_layers", "latent_dim"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
                raise ValueError(f"ACTConfig.{name} must be a positive int, got {value!r}")
        if self.dim_model % self.n_heads:
            raise ValueError(f"ACTConfig.dim_model ({self.dim_model}) must be divisible by n_heads ({self.n_heads})")
        if self.dim_model % 4:
            raise ValueError(f"ACTConfig.dim_model must be a multiple of 4 (2-D sine positions), got {self.dim_model}")
        if self.backbone not in BACKBONES:
            raise ValueError(f"ACTConfig.backbone must be one of {BACKBONES}, got {self.backbone!r}")
        self.camera_size = _size_pair(self.camera_size, "camera_size")
        self.tactile_size = _size_pair(self.tactile_size, "tactile_size")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"ACTConfig.dropout must be in [0, 1), got {self.dropout!r}")
        for name in ("kl_weight", "weight_decay", "temporal_ensemble_coeff"):
            if getattr(self, name) < 0:
                raise ValueError(f"ACTConfig.{name} must be >= 0, got {getattr(self, name)!r}")
        for name in ("lr", "lr_backbone"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ACTConfig.{name} must be > 0, got {getattr(self, name)!r}")

    @classmethod
    def from_preset(cls, preset: str, **overrides) -> "ACTConfig":
        """``gpu``: ResNet-18 backbones, dim 512 (ACT's sizes). ``cpu``: small CNN, dim 128, small
        images, no dropout (dropout is ~20 % of a CPU step and short runs underfit rather than overfit);
        trains on 2 cores in minutes and infers one chunk in well under 30 ms."""
        if preset == "gpu":
            base = dict(backbone="resnet18", camera_size=(240, 320), tactile_size=(240, 320), dim_model=512,
                        n_heads=8, dim_feedforward=3200, n_encoder_layers=4, n_decoder_layers=1,
                        n_vae_encoder_layers=4, latent_dim=32, lr=1e-5, lr_backbone=1e-5)
        elif preset == "cpu":
            base = dict(backbone="small_cnn", camera_size=(60, 80), tactile_size=(48, 64), dim_model=128,
                        n_heads=4, dim_feedforward=512, n_encoder_layers=2, n_decoder_layers=1,
                        n_vae_encoder_layers=2, latent_dim=16, dropout=0.0, lr=3e-4, lr_backbone=3e-4)
        else:
            raise ValueError(f"ACT preset must be 'cpu' or 'gpu', got {preset!r}")
        base.update(overrides)
        return cls(preset=preset, **base)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        for k, v in d.items():
            if isinstance(v, tuple):
                d[k] = list(v)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ACTConfig":
        """Inverse of :meth:`to_dict`; unknown keys are an error (a checkpoint from another version)."""
        if not isinstance(d, dict):
            raise ValueError(f"ACT config must be a JSON object, got {type(d).__name__}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"ACT config has unknown fields {unknown}; expected a subset of {sorted(known)}")
        return cls(**d)

    @property
    def input_keys(self) -> list[str]:
        """Batch keys the model reads (LeRobot-style names, as produced by EpisodeDataset)."""
        keys = ["observation.qpos"]
        keys += [f"observation.images.{c}" for c in self.camera_names]
        keys += [f"observation.tactile.{s}" for s in self.tactile_names]
        keys += [f"observation.tactile_background.{s}" for s in self.tactile_names]
        return keys
