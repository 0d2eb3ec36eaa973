"""Compact deep-compression-style autoencoder for tactile residuals (f = 2**stages, few channels).

Down stages move space into channels (pixel-unshuffle) and mix with a 1x1 conv, so the shortcut
path carries the signal losslessly and the residual blocks only refine it; the decoder mirrors this
with pixel-shuffle. Input/output: residual images scaled to [-1, 1], shape (B, 3, H, W).
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from controltac_il.generator.config import AutoencoderConfig


class ResBlock(nn.Module):
    """x + conv3x3(SiLU(conv3x3(SiLU(x)))), the second conv zero-initialised (identity at init)."""

    def __init__(self, channels: int):
        super().__init__()
        self.conv1 = nn.Conv2d(channels, channels, 3, padding=1)
        self.conv2 = nn.Conv2d(channels, channels, 3, padding=1)
        nn.init.zeros_(self.conv2.weight)
        nn.init.zeros_(self.conv2.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv2(F.silu(self.conv1(F.silu(x))))


class Down(nn.Module):
    """Halve H, W: pixel-unshuffle (C -> 4C) then a 1x1 conv to ``out_ch``."""

    def __init__(self, in_ch: int, out_ch: int):
        super().__init__()
        self.proj = nn.Conv2d(4 * in_ch, out_ch, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(F.pixel_unshuffle(x, 2))


class Up(nn.Module):
    """Double H, W: a 1x1 conv to 4 * ``out_ch`` then pixel-shuffle."""

    def __init__(self, in_ch: int, out_ch: int):
        super().__init__()
        self.proj = nn.Conv2d(in_ch, 4 * out_ch, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.pixel_shuffle(self.proj(x), 2)


class TactileAutoencoder(nn.Module):
    """Residual image (B, 3, H, W) in [-1, 1] <-> latent (B, C, H/f, W/f)."""

    def __init__(self, config: AutoencoderConfig):
        super().__init__()
        self.config = config
        ch = (config.stem_channels, *config.channels)
        enc: list[nn.Module] = [nn.Conv2d(3, ch[0], 3, padding=1)]
        for i in range(len(config.channels)):
            enc.append(Down(ch[i], ch[i + 1]))
            enc.extend(ResBlock(ch[i + 1]) for _ in range(config.blocks_per_stage))
        enc += [nn.SiLU(), nn.Conv2d(ch[-1], config.latent_channels, 3, padding=1)]
        self.encoder = nn.Sequential(*enc)

        dec: list[nn.Module] = [nn.Conv2d(config.latent_channels, ch[-1], 3, padding=1)]
        for i in range(len(config.channels), 0, -1):
            dec.extend(ResBlock(ch[i]) for _ in range(config.blocks_per_stage))
            dec.append(Up(ch[i], ch[i - 1]))
        dec += [nn.SiLU(), nn.Conv2d(ch[0], 3, 3, padding=1)]
        self.decoder = nn.Sequential(*dec)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        return self.encoder(x)

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        return self.decoder(z)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.decode(self.encode(x))


CONTACT_LEVEL = 12.0 / 128  # residual magnitude (unit scale) above which a pixel counts as contact


def autoencoder_loss(recon: torch.Tensor, target: torch.Tensor, contact_weight: float = 0.0) -> torch.Tensor:
    """L1 + MSE + L1 of the image gradients (keeps contact edges sharp), per pixel weighted by
    ``1 + contact_weight`` where the target shows contact (contacts are a small share of the pad)."""
    w = 1.0 + contact_weight * (target.abs().amax(dim=1, keepdim=True) > CONTACT_LEVEL).float()
    d = recon - target
    dy, dx = d[..., 1:, :] - d[..., :-1, :], d[..., :, 1:] - d[..., :, :-1]
    return ((w * (d.abs() + d * d)).mean()
            + 0.5 * ((w[..., 1:, :] * dy.abs()).mean() + (w[..., :, 1:] * dx.abs()).mean()))
