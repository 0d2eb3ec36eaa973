"""ACT configuration: one pydantic dataclass (every field validated at construction), two presets (``gpu`` as in the paper, ``cpu`` for 2 cores).

Defaults follow ACT (Zhao et al. 2023) and the ControlTac imitation-learning setting: action chunk
N_a = 20, KL weight 10, one decoder layer (what the original implementation effectively uses),
temporal-ensembling weights exp(-0.01 i).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import AfterValidator, Field, model_validator
from pydantic.dataclasses import dataclass

from controltac_il.config import JsonConfig, PosInt, Positive, STRICT, one_line_errors
from controltac_il.streams import HDF5, HDF5_STATE, background_key, image_key, tactile_key

NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]


def _stream_names(names: tuple[str, ...]) -> tuple[str, ...]:
    if any(not n or "." in n or "/" in n for n in names):
        raise ValueError(f"must be non-empty names without '.' or '/', got {names!r}")
    if len(set(names)) != len(names):
        raise ValueError(f"has duplicates: {names!r}")
    return names


Names = Annotated[tuple[str, ...], AfterValidator(_stream_names)]


@one_line_errors
@dataclass(config=STRICT)
class ACTConfig(JsonConfig):
    """Architecture and loss of the ACT policy (CVAE with a transformer encoder/decoder).

    Every field is validated when the config is built (pydantic; a ValueError names the field); ``from_dict``
    refuses unknown keys (a checkpoint from another version).

    Data layout (must match the episodes the policy is trained on and deployed with):
        camera_names: RGB cameras, e.g. ("third_view", "wrist"); each is one image stream.
        tactile_names: tactile sensors, e.g. ("left", "right"); each is one image stream, fed as the
            background-subtracted residual (image - background) / 255 in [-1, 1]. Names: unique,
            non-empty, without '.' or '/'; at least one stream (camera or tactile) in all.
        state_dim: length D of the proprioception vector ``observation.qpos``.
        action_dim: length A of one action (scene: [x, y, z, yaw, gripper] -> 5).
        chunk_size: N_a, actions predicted per inference (paper: 20 at 10 Hz).

    Image streams:
        backbone: "resnet18" (ResNet-18 written in this repo, stride 32) or "small_cnn" (4 strided
            3x3 convs, stride 16). Cameras share one backbone, tactile sensors another.
        camera_size / tactile_size: (H, W) in pixels every camera / tactile frame is resized to
            before its backbone.

    Transformer:
        dim_model: token width (a multiple of 4 and of n_heads); n_heads: attention heads;
        dim_feedforward: MLP width; n_encoder_layers / n_decoder_layers: main transformer depth
        (decoder: 1, as in ACT); n_vae_encoder_layers: depth of the CVAE encoder over
        [CLS, qpos, action chunk]; latent_dim: size of the CVAE style variable z (0-mean prior;
        z = 0 at inference); dropout: dropout in the transformer layers, in [0, 1).

    Loss and optimisation:
        kl_weight: weight (>= 0) of KL(q(z|a, s) || N(0, I)) added to the masked L1 on actions (ACT: 10).
        lr / lr_backbone / weight_decay: AdamW learning rates (> 0; transformer, image backbones) and decay (>= 0).
        temporal_ensemble_coeff: k >= 0 in the ensembling weights exp(-k i), i = age of a prediction.

    preset: the preset the config was built from ("gpu", "cpu"), or "custom".
    """

    camera_names: Names = ("third_view", "wrist")
    tactile_names: Names = ("left", "right")
    state_dim: PosInt = 5
    action_dim: PosInt = 5
    chunk_size: PosInt = 20
    backbone: Literal["resnet18", "small_cnn"] = "resnet18"
    camera_size: tuple[PosInt, PosInt] = (240, 320)
    tactile_size: tuple[PosInt, PosInt] = (240, 320)
    dim_model: PosInt = 512
    n_heads: PosInt = 8
    dim_feedforward: PosInt = 3200
    n_encoder_layers: PosInt = 4
    n_decoder_layers: PosInt = 1
    n_vae_encoder_layers: PosInt = 4
    latent_dim: PosInt = 32
    dropout: Annotated[float, Field(ge=0, lt=1)] = 0.1
    kl_weight: NonNeg = 10.0
    lr: Positive = 1e-5
    lr_backbone: Positive = 1e-5
    weight_decay: NonNeg = 1e-4
    temporal_ensemble_coeff: NonNeg = 0.01
    preset: Literal["gpu", "cpu", "custom"] = "custom"

    @model_validator(mode="after")
    def _consistent(self):
        if not self.camera_names and not self.tactile_names:
            raise ValueError("ACTConfig needs at least one image stream (camera_names or tactile_names)")
        if self.dim_model % self.n_heads or self.dim_model % 4:
            raise ValueError(f"dim_model ({self.dim_model}) must be divisible by n_heads ({self.n_heads}) and by 4 "
                             "(2-D sine positions)")
        return self

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

    @property
    def input_keys(self) -> list[str]:
        """Batch keys the model reads (LeRobot-style names, as produced by EpisodeDataset)."""
        keys = [HDF5_STATE]
        keys += [image_key(c, HDF5) for c in self.camera_names]
        keys += [tactile_key(s, HDF5) for s in self.tactile_names]
        keys += [background_key(s, HDF5) for s in self.tactile_names]
        return keys
