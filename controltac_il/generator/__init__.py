"""Stage-1 force-control generator (ControlTac): reference tactile residual + ΔF -> residual at the target force.

Modules: ``config`` (pydantic dataclasses), ``autoencoder`` (compact residual codec), ``dit`` (ΔF-conditioned
diffusion transformer), ``sampler`` (DDIM via diffusers), ``checkpoint`` (safetensors + JSON + model card,
``controltac_il.checkpoint``), ``pipeline`` (``ForceGenerator``, the inference API), ``data``, ``objectives`` (the
denoiser's training objective and EMA, stage 1 and 2 alike), ``stages`` (autoencoder, latents, DiT of a run),
``shipped`` (the shipped checkpoints by name), ``train_config`` and ``train`` (the training CLI). Stage 2, the pose-control adapter over a frozen stage 1: ``adapter``, ``pose_data``
and ``train_pose`` (its training CLI, the job in ``pose_training``); ``ForceGenerator.generate(..., mask=...)`` uses it.
"""

from controltac_il.lazy import exports

_EXPORTS = {**dict.fromkeys(("AutoencoderConfig", "DiffusionConfig", "DiTConfig", "GeneratorConfig"),
                            "controltac_il.generator.config"),
            **dict.fromkeys(("ForceGenerator", "RangeReport"), "controltac_il.generator.pipeline")}
__getattr__, __dir__ = exports(__name__, _EXPORTS)
__all__ = list(_EXPORTS)
