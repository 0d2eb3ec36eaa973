"""Diffusion transformer denoiser in DiT's style, conditioned on the diffusion timestep and ΔF.

Input: the noisy latent concatenated in channels with the reference latent, (B, 2C, h, w); it is
cut into p x p patches (tokens), given fixed 2-D sin-cos positions, and passed through adaLN-Zero
blocks whose scale/shift/gate come from ``timestep embedding + ΔF embedding``; a final adaLN layer
maps tokens back to a (B, C, h, w) prediction (noise or clean sample, per the diffusion config).
Optionally (``conv_head_width > 0``) a local refinement head, as in U-ViT's final convolution, adds a
per-pixel correction at latent resolution: a patch token sees the contact only at p x p granularity,
and the contact edge moves by less than a patch as the force changes.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from controltac_il.generator.config import DiTConfig


def timestep_features(t: torch.Tensor, dim: int, max_period: float = 10000.0) -> torch.Tensor:
    """Sinusoidal features of (B,) timesteps -> (B, dim)."""
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, dtype=torch.float32, device=t.device) / half)
    args = t.float()[:, None] * freqs[None]
    return torch.cat([torch.cos(args), torch.sin(args)], dim=-1)


def sincos_pos_embed(dim: int, h: int, w: int) -> torch.Tensor:
    """Fixed 2-D sin-cos positional embedding, (h*w, dim): half the channels code rows, half columns."""

    def one_axis(d: int, pos: torch.Tensor) -> torch.Tensor:
        omega = 1.0 / 10000 ** (torch.arange(d // 2, dtype=torch.float64) / (d / 2))
        out = pos.reshape(-1, 1).double() * omega[None]
        return torch.cat([torch.sin(out), torch.cos(out)], dim=1)

    gy, gx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    return torch.cat([one_axis(dim // 2, gy), one_axis(dim // 2, gx)], dim=1).float()


class Embedder(nn.Module):
    """Linear -> SiLU -> Linear MLP from ``in_dim`` features to ``hidden`` (timestep or ΔF)."""

    def __init__(self, in_dim: int, hidden: int):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(in_dim, hidden), nn.SiLU(), nn.Linear(hidden, hidden))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.mlp(x)


def modulate(x: torch.Tensor, shift: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    return x * (1 + scale[:, None]) + shift[:, None]


class DiTBlock(nn.Module):
    """Pre-norm attention + MLP block with adaLN-Zero conditioning (gates start at zero)."""

    def __init__(self, hidden: int, heads: int, mlp_ratio: float):
        super().__init__()
        self.heads = heads
        self.norm1 = nn.LayerNorm(hidden, elementwise_affine=False, eps=1e-6)
        self.qkv = nn.Linear(hidden, 3 * hidden)
        self.proj = nn.Linear(hidden, hidden)
        self.norm2 = nn.LayerNorm(hidden, elementwise_affine=False, eps=1e-6)
        mlp_hidden = int(hidden * mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(hidden, mlp_hidden), nn.GELU(approximate="tanh"), nn.Linear(mlp_hidden, hidden))
        self.ada = nn.Sequential(nn.SiLU(), nn.Linear(hidden, 6 * hidden))
        nn.init.zeros_(self.ada[1].weight)
        nn.init.zeros_(self.ada[1].bias)

    def forward(self, x: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        shift1, scale1, gate1, shift2, scale2, gate2 = self.ada(c).chunk(6, dim=-1)
        b, n, d = x.shape
        h = modulate(self.norm1(x), shift1, scale1)
        q, k, v = self.qkv(h).reshape(b, n, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        a = F.scaled_dot_product_attention(q, k, v).transpose(1, 2).reshape(b, n, d)
        x = x + gate1[:, None] * self.proj(a)
        x = x + gate2[:, None] * self.mlp(modulate(self.norm2(x), shift2, scale2))
        return x


class LocalRefinementHead(nn.Module):
    """Three 3x3 convolutions on [DiT output, z_ref, x_t] (3C channels) -> (B, C, h, w) correction.

    The last convolution starts at zero, so a fresh head leaves the DiT output unchanged.
    """

    def __init__(self, channels: int, width: int):
        super().__init__()
        self.net = nn.Sequential(nn.Conv2d(3 * channels, width, 3, padding=1), nn.SiLU(),
                                 nn.Conv2d(width, width, 3, padding=1), nn.SiLU(),
                                 nn.Conv2d(width, channels, 3, padding=1))
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)

    def forward(self, out: torch.Tensor, z_ref: torch.Tensor, x_t: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([out, z_ref, x_t], dim=1))


def force_condition(delta_force: np.ndarray, reference_force: np.ndarray | None, config: DiTConfig) -> np.ndarray:
    """What a DiT of ``config`` is conditioned on: ΔF (B, 3) N, with ``config.reference_force`` followed by the
    reference's force (B, 3) N, (B, 6) float32; ValueError when such a DiT gets no reference force."""
    delta_force = np.asarray(delta_force, np.float32)
    if not config.reference_force:
        return delta_force
    if reference_force is None:
        raise ValueError("reference_force (B, 3) N is required: this generator is conditioned on the reference's "
                         "own force")
    return np.concatenate([delta_force, np.asarray(reference_force, np.float32)], axis=-1)


class ForceDiT(nn.Module):
    """Denoiser ε_θ(x_t, z_ref, t, ΔF) (or x0 predictor): (B, C, h, w) latents -> (B, C, h, w)."""

    def __init__(self, config: DiTConfig):
        super().__init__()
        self.config = config
        c, p, d = config.in_channels, config.patch_size, config.hidden_size
        self.patch_embed = nn.Conv2d(2 * c, d, kernel_size=p, stride=p)
        self.t_embedder = Embedder(256, d)
        self.f_embedder = Embedder(3, d)
        self.r_embedder = Embedder(3, d) if config.reference_force else None
        if self.r_embedder is not None:  # starts as the model without it (a fine-tune from one changes nothing)
            nn.init.zeros_(self.r_embedder.mlp[2].weight)
            nn.init.zeros_(self.r_embedder.mlp[2].bias)
        self.register_buffer("force_scale", torch.tensor(config.force_scale, dtype=torch.float32), persistent=False)
        self.blocks = nn.ModuleList(DiTBlock(d, config.num_heads, config.mlp_ratio) for _ in range(config.depth))
        self.final_norm = nn.LayerNorm(d, elementwise_affine=False, eps=1e-6)
        self.final_ada = nn.Sequential(nn.SiLU(), nn.Linear(d, 2 * d))
        self.final_linear = nn.Linear(d, p * p * c)
        for m in (self.final_ada[1], self.final_linear):
            nn.init.zeros_(m.weight)
            nn.init.zeros_(m.bias)
        self.refine = LocalRefinementHead(c, config.conv_head_width) if config.conv_head_width else None
        self._pos_cache: dict[tuple[int, int], torch.Tensor] = {}

    def _pos(self, h: int, w: int, like: torch.Tensor) -> torch.Tensor:
        if (h, w) not in self._pos_cache:
            self._pos_cache[(h, w)] = sincos_pos_embed(self.config.hidden_size, h, w)
        return self._pos_cache[(h, w)].to(device=like.device, dtype=like.dtype)

    def embed(self, x_t: torch.Tensor, z_ref: torch.Tensor, t: torch.Tensor, delta_force: torch.Tensor
              ) -> tuple[torch.Tensor, torch.Tensor]:
        """Patch tokens with positions (B, N, d) and the conditioning vector (B, d) of timestep + the force
        condition (B, 3) ΔF N, or (B, 6) [ΔF, F_ref] N with ``config.reference_force``)."""
        width = 6 if self.r_embedder is not None else 3
        if delta_force.shape[-1] != width:
            raise ValueError(f"the force condition is (B, {width}) for this DiT (reference_force="
                             f"{self.r_embedder is not None}), got {tuple(delta_force.shape)}")
        tok = self.patch_embed(torch.cat([x_t, z_ref], dim=1))  # (B, d, h/p, w/p)
        gh, gw = tok.shape[-2:]
        tok = tok.flatten(2).transpose(1, 2)
        tok = tok + self._pos(gh, gw, tok)
        cond = self.t_embedder(timestep_features(t, 256).to(tok.dtype))
        cond = cond + self.f_embedder((delta_force[:, :3].float() / self.force_scale).to(tok.dtype))
        if self.r_embedder is not None:
            cond = cond + self.r_embedder((delta_force[:, 3:].float() / self.force_scale).to(tok.dtype))
        return tok, cond

    def head(self, tok: torch.Tensor, cond: torch.Tensor, x_t: torch.Tensor, z_ref: torch.Tensor) -> torch.Tensor:
        """Tokens after the blocks -> prediction (B, C, h, w) (final adaLN layer, unpatchify, refinement head)."""
        c, p = self.config.in_channels, self.config.patch_size
        b, _, h, w = x_t.shape
        shift, scale = self.final_ada(cond).chunk(2, dim=-1)
        out = self.final_linear(modulate(self.final_norm(tok), shift, scale))  # (B, N, p*p*c)
        out = out.reshape(b, h // p, w // p, p, p, c).permute(0, 5, 1, 3, 2, 4).reshape(b, c, h, w)
        if self.refine is not None:
            out = out + self.refine(out, z_ref, x_t)
        return out

    def forward(self, x_t: torch.Tensor, z_ref: torch.Tensor, t: torch.Tensor, delta_force: torch.Tensor) -> torch.Tensor:
        """x_t, z_ref: (B, C, h, w); t: (B,) timesteps; delta_force: (B, 3) in N."""
        tok, cond = self.embed(x_t, z_ref, t, delta_force)
        for blk in self.blocks:
            tok = blk(tok, cond)
        return self.head(tok, cond, x_t, z_ref)
