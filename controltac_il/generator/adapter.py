"""Stage-2 pose-control adapter: a binary contact mask at the target pose steers the frozen stage-1 denoiser.

ControlNet for a DiT: a trainable copy of the denoiser's blocks (the control branch) sees the frozen patch tokens
plus the encoded mask; after each block its tokens enter the frozen branch through a zero-initialised linear
layer, and a zero-initialised convolution on [frozen output, encoded mask] corrects the prediction at latent
resolution (a token spans p x p latent pixels; the contact's outline is finer). Every connection into the
frozen model starts at zero, so an untrained adapter gives exactly stage 1's prediction.
"""

from __future__ import annotations

import copy

import cv2
import numpy as np
import torch
from torch import nn

from controltac_il.generator.config import PoseAdapterConfig
from controltac_il.generator.dit import ForceDiT


def masks_to_model(masks: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """bool (B, h, w) masks -> float32 (B, 1, H, W) coverage in [0, 1] at the model's ``size`` = (H, W) (area
    resize), the adapter's mask input."""
    h, w = size
    out = np.stack([m.astype(np.float32) if m.shape == (h, w) else
                    cv2.resize(m.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) for m in masks])
    return out[:, None]


def _zero(m: nn.Module) -> nn.Module:
    nn.init.zeros_(m.weight)
    nn.init.zeros_(m.bias)
    return m


class MaskEncoder(nn.Module):
    """Soft mask (B, 1, H, W) in [0, 1] at the model size -> features (B, k, H/f, W/f) at the latent size.

    Space-to-depth by f first (lossless: each latent pixel sees its f x f mask pixels as channels), then two
    3x3 convolutions at the latent size (a full-resolution stem costs twice the whole denoiser)."""

    def __init__(self, factor: int, channels: int):
        super().__init__()
        self.net = nn.Sequential(nn.PixelUnshuffle(factor), nn.Conv2d(factor * factor, channels, 3, padding=1),
                                 nn.SiLU(), nn.Conv2d(channels, channels, 3, padding=1))

    def forward(self, mask: torch.Tensor) -> torch.Tensor:
        return self.net(mask)


class PoseAdapter(nn.Module):
    """The trainable part of stage 2; ``forward`` runs it with the frozen ``denoiser`` it was made for."""

    def __init__(self, config: PoseAdapterConfig, denoiser: ForceDiT | None = None):
        super().__init__()
        self.config = config
        dit = config.base.dit
        d, p, c, k = dit.hidden_size, dit.patch_size, dit.in_channels, config.mask_channels
        base = denoiser if denoiser is not None else ForceDiT(dit)
        self.mask_encoder = MaskEncoder(config.base.autoencoder.factor, k)
        self.mask_patch = nn.Conv2d(k, d, kernel_size=p, stride=p)
        self.mask_in = _zero(nn.Linear(d, d))
        self.blocks = copy.deepcopy(base.blocks).requires_grad_(True)  # the control branch starts as the frozen blocks
        self.block_out = nn.ModuleList(_zero(nn.Linear(d, d)) for _ in self.blocks)
        self.out = nn.Sequential(nn.Conv2d(c + k, config.head_width, 3, padding=1), nn.SiLU(),
                                 _zero(nn.Conv2d(config.head_width, c, 3, padding=1)))

    def forward(self, denoiser: ForceDiT, x_t: torch.Tensor, z_ref: torch.Tensor, t: torch.Tensor,
                delta_force: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Stage 2's prediction (B, C, h, w): as ``denoiser(x_t, z_ref, t, delta_force)`` steered by ``mask``,
        (B, 1, H, W) in [0, 1] at the model's image size (the target pose's contact)."""
        tok, cond = denoiser.embed(x_t, z_ref, t, delta_force)
        m = self.mask_encoder(mask.to(tok.dtype))
        ctrl = tok + self.mask_in(self.mask_patch(m).flatten(2).transpose(1, 2))
        for blk, ctl, zero in zip(denoiser.blocks, self.blocks, self.block_out):
            ctrl = ctl(ctrl, cond)
            tok = blk(tok, cond) + zero(ctrl)
        out = denoiser.head(tok, cond, x_t, z_ref)
        return out + self.out(torch.cat([out, m], dim=1))


class PoseControlledDenoiser(nn.Module):
    """A denoiser with the ``ForceDiT`` call signature for the sampler: the frozen stage-1 denoiser, the adapter
    and one batch's masks bound (``ddim_sample`` calls it as ``model(x_t, z_ref, t, delta_force)``)."""

    def __init__(self, denoiser: ForceDiT, adapter: PoseAdapter, mask: torch.Tensor):
        super().__init__()
        self.denoiser, self.adapter, self.mask = denoiser, adapter, mask

    def forward(self, x_t, z_ref, t, delta_force):
        return self.adapter(self.denoiser, x_t, z_ref, t, delta_force, self.mask)
