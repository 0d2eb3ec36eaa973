"""Force estimator: tactile residual (H, W, 3) uint8 -> [Fx, Fy, Fz] in N, sensor frame.

A compact CNN trained from scratch on sensor-model residuals (the paper uses a DINOv2 ViT whose
weights cannot be downloaded here). ``ForceEstimator.from_pretrained()`` loads the shipped
checkpoint; ``python -m controltac_il.estimators.train`` trains one.
"""

from controltac_il.estimators.config import EstimatorConfig
from controltac_il.estimators.estimator import ForceEstimator, validate_residuals
from controltac_il.estimators.fit import EstimatorTrainConfig, fit

__all__ = ["EstimatorConfig", "ForceEstimator", "EstimatorTrainConfig", "fit", "validate_residuals"]
