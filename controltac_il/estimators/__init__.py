"""Force estimator: tactile residual (H, W, 3) uint8 -> [Fx, Fy, Fz] in N, sensor frame.

A compact CNN trained from scratch on sensor-model residuals (the paper uses a DINOv2 ViT whose
weights cannot be downloaded here). ``ForceEstimator.from_pretrained()`` loads the shipped
checkpoint; ``python -m controltac_il.estimators.train`` trains one.
"""

from controltac_il.lazy import exports

_EXPORTS = {**dict.fromkeys(("EstimatorConfig", "EstimatorTrainConfig"), "controltac_il.estimators.config"),
            **dict.fromkeys(("ForceEstimator", "validate_residuals"), "controltac_il.estimators.estimator"),
            "fit": "controltac_il.estimators.fit"}
__getattr__, __dir__ = exports(__name__, _EXPORTS)
__all__ = list(_EXPORTS)
