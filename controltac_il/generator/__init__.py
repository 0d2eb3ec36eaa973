"""Stage-1 force-control generator (ControlTac): reference tactile residual + ΔF -> residual at the target force.

Modules: ``config`` (pydantic dataclasses), ``autoencoder`` (compact residual codec), ``dit`` (ΔF-conditioned
diffusion transformer), ``sampler`` (DDIM via diffusers), ``checkpoint`` (safetensors + JSON + model card,
``controltac_il.checkpoint``), ``pipeline`` (``ForceGenerator``, the inference API and its sampling loop),
``inputs`` (its input checks and range decision), ``masks`` (stage 2's target-pose masks), ``forces`` (the validated
force range), ``shipped`` (the shipped checkpoints by name), ``training`` (the package that trains both stages, one
CLI: ``python -m controltac_il.generator.training stage1|stage2``). Stage 2, the pose-control adapter over a frozen
stage 1: ``adapter`` (its network; its data and job in ``training``); ``ForceGenerator.generate(..., mask=...)``
uses it.
"""

from controltac_il.lazy import exports

_EXPORTS = {**dict.fromkeys(("AutoencoderConfig", "DiffusionConfig", "DiTConfig", "GeneratorConfig"),
                            "controltac_il.generator.config"),
            **dict.fromkeys(("ForceGenerator", "Generation"), "controltac_il.generator.pipeline")}
__getattr__, __dir__ = exports(__name__, _EXPORTS)
__all__ = list(_EXPORTS)
