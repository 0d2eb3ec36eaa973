"""DDIM sampling of the latent force delta with diffusers' DDIMScheduler (deterministic, eta = 0).

``trailing`` timestep spacing makes every step count from 1 up start at the last training
timestep, so a 1-step sample is a proper (if coarse) prediction from pure noise.
"""

from __future__ import annotations

from typing import Sequence

import torch
from diffusers import DDIMScheduler

from controltac_il.generator.config import DiffusionConfig
from controltac_il.generator.dit import ForceDiT


def make_scheduler(config: DiffusionConfig) -> DDIMScheduler:
    """Training/sampling noise schedule for ``config`` (no sample clipping: latents are unbounded)."""
    return DDIMScheduler(
        num_train_timesteps=config.num_train_timesteps,
        beta_schedule=config.beta_schedule,
        prediction_type=config.prediction_type,
        timestep_spacing="trailing",
        clip_sample=False,
        set_alpha_to_one=True,
    )


def seeded_noise(seeds: Sequence[int], shape: tuple[int, ...]) -> torch.Tensor:
    """(len(seeds), *shape) float32 standard normal noise, row i a pure function of seeds[i]."""
    rows = []
    cache: dict[int, torch.Tensor] = {}
    for s in seeds:
        if s not in cache:
            g = torch.Generator().manual_seed(int(s))
            cache[s] = torch.randn(shape, generator=g)
        rows.append(cache[s])
    return torch.stack(rows)


@torch.no_grad()
def ddim_sample(denoiser: ForceDiT, scheduler: DDIMScheduler, z_ref: torch.Tensor, delta_force: torch.Tensor,
                noise: torch.Tensor, steps: int) -> torch.Tensor:
    """Run ``steps`` DDIM steps from ``noise``; returns the clean normalised latent delta (B, C, h, w).

    z_ref: normalised reference latent (B, C, h, w); delta_force: the force condition, (B, 3) ΔF N or (B, 6)
    [ΔF, F_ref] N (``dit.force_condition``); noise like z_ref.
    The scheduler arithmetic runs in float32 whatever the model's dtype.
    """
    scheduler.set_timesteps(steps)
    x = noise.float()
    for t in scheduler.timesteps:
        tt = torch.full((x.shape[0],), int(t), device=x.device, dtype=torch.long)
        out = denoiser(x.to(z_ref.dtype), z_ref, tt, delta_force).float()
        x = scheduler.step(out, int(t), x, eta=0.0).prev_sample
    return x
