"""GelSight-Mini-style tactile sensor model: contact + force in, tactile image out.

Pipeline (one module per step)::

    indenters.py  object height field (mm) at a pose (x, y, θ) on the pad
    mechanics.py  depth for a target normal force (bracketed monotone solve), elastic gel surface, shear
    optics.py     gel height → surface gradients → RGB (three-light model or Taxim polynomial lookup),
                  over a real GelSight Mini background, with vignetting and sensor noise
    sensor.py     ``TactileSensor``: the facade the rest of the project uses
    residual.py   background subtraction with the 127 offset, contact mask and area
    dataset.py    FeelAnyForce-layout writer and loader

Conventions: images are uint8 RGB (H, W, 3); lengths in mm; forces [Fx, Fy, Fz] in N in the
sensor frame: x along image columns (right), y along image rows upwards, z normal to the gel
pointing into the sensor, so Fz > 0 when an object presses.
"""

from controltac_il.lazy import exports

_EXPORTS = {"SensorSpec": "controltac_il.tactile.spec",
            **dict.fromkeys(("HELDOUT_OBJECTS", "INDENTERS", "TRAIN_OBJECTS", "Indenter", "get_indenter"),
                            "controltac_il.tactile.indenters"),
            **dict.fromkeys(("contact_mask", "from_residual", "to_residual"), "controltac_il.tactile.residual"),
            **dict.fromkeys(("Contact", "TactileSensor"), "controltac_il.tactile.sensor")}
__getattr__, __dir__ = exports(__name__, _EXPORTS)
__all__ = list(_EXPORTS)
