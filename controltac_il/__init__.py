"""controltac-il: force-controlled tactile image generation for imitation learning.

Subpackages: ``tactile`` (GelSight-style sensor model), ``generator`` (ControlTac stage 1),
``estimators`` (force reader), ``datasets`` (ACT HDF5 episodes), ``augment`` (ForceAugment).
"""

__version__ = "0.1.0"
