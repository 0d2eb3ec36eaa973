"""The training objective of the generator's denoiser, shared by stage 1 (``stage1``) and the stage-2 pose adapter
(``stage2``): a noised batch of latent changes, the 0.5 L1 + 0.5 MSE prediction loss, and the EMA of the
weights that both ship."""

from __future__ import annotations

import torch
from diffusers.training_utils import EMAModel
from torch.nn import functional as F

from controltac_il.generator.config import GeneratorConfig


def ema_weights(ema: EMAModel, model: torch.nn.Module) -> dict[str, torch.Tensor]:
    """The EMA as ``model``'s state dict (EMA parameters, the model's buffers)."""
    return {**model.state_dict(), **dict(zip((n for n, _ in model.named_parameters()), ema.shadow_params))}


def noised_batch(gcfg: GeneratorConfig, sched, x0: torch.Tensor, one_step_fraction: float, seed: int
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(x_t, t, target) of one training batch: x0 noised at uniform timesteps (``one_step_fraction`` of them at the
    last, the one a 1-step sampler visits); the target is the noise or x0 per the prediction type."""
    n, steps = len(x0), gcfg.diffusion.num_train_timesteps
    g = torch.Generator().manual_seed(seed)
    noise = torch.randn(x0.shape, generator=g).to(x0.device)
    t = torch.randint(0, steps, (n,), generator=g)
    if one_step_fraction > 0:
        t[torch.rand(n, generator=g) < one_step_fraction] = steps - 1
    t = t.to(x0.device)
    return sched.add_noise(x0, noise, t), t, noise if gcfg.diffusion.prediction_type == "epsilon" else x0


def prediction_loss(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """0.5 L1 + 0.5 MSE; ``weight`` (broadcast to ``pred``): a weighted mean instead, sum(w · e) / sum(w)."""
    if weight is None:
        return 0.5 * F.l1_loss(pred, target) + 0.5 * F.mse_loss(pred, target)
    w = weight.expand_as(pred)
    err = 0.5 * (pred - target).abs() + 0.5 * (pred - target).square()
    return (w * err).sum() / w.sum()


def restore_ema(ema: EMAModel, model: torch.nn.Module, tensors: dict[str, torch.Tensor], optimization_step: int) -> None:
    """Load the ``ema.<parameter>`` tensors of a run state (:func:`ema_weights` saved) into ``ema``."""
    device = next(model.parameters()).device
    ema.load_state_dict({"optimization_step": optimization_step, "shadow_params":
                         [tensors[f"ema.{n}"].float().clone().to(device) for n, _ in model.named_parameters()]})
