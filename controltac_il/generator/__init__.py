"""Stage-1 force-control generator (ControlTac): reference tactile residual + ΔF -> residual at the target force.

Modules: ``config`` (pydantic dataclasses), ``autoencoder`` (compact residual codec), ``dit`` (ΔF-conditioned
diffusion transformer), ``sampler`` (DDIM via diffusers), ``checkpoint`` (safetensors + JSON + model card,
``controltac_il.checkpoint``), ``pipeline`` (``ForceGenerator``, the inference API), ``data``, ``train_config``
and ``train`` (training CLI).
"""

from controltac_il.generator.config import (
    AutoencoderConfig,
    DiffusionConfig,
    DiTConfig,
    GeneratorConfig,
)
from controltac_il.generator.pipeline import ForceGenerator, RangeReport

__all__ = [
    "AutoencoderConfig",
    "DiTConfig",
    "DiffusionConfig",
    "GeneratorConfig",
    "ForceGenerator",
    "RangeReport",
]
