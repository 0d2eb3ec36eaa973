"""``python -m controltac_il.calibrate``: fit the force estimator and the generator to a lab's own sensor.

    python -m controltac_il.calibrate record --setup my_ur.yaml --start X Y Z YAW --out DIR   # presses, recorded
    python -m controltac_il.calibrate --recordings DIR --out my_sensor --lag auto   # videos + force CSVs
    python -m controltac_il.calibrate --presses DIR --out my_sensor                 # or the FeelAnyForce layout
    ForceAugment(dataset, generator="my_sensor")                                    # its estimator too
    python -m controltac_il.augment --generator my_sensor ...

From a few dozen Fz-labelled frames (5-15 grasps) of a sensor it never saw: the estimator gets a colour adapter
before its frozen network (``estimators.few_shot``), the generator a fine-tune (autoencoder, then DiT). Each is
measured on held-out grasps and the table is printed, kept in the bundle and drawn in ``report.png``. When the
estimator does not beat predicting the constant mean on held-out grasps, a one-line warning says so and
ForceAugment takes the nominal reference force for unlabelled frames with this bundle. Recordings
(``calibrate.recordings``) are cut into loading ramps with a background per recording and written in the presses
layout. The bundle OUT::

    estimator/          the calibrated estimator (a checkpoint folder)
    generator/          the fine-tuned generator (a checkpoint folder)
    presses/            with --recordings: the frames kept, in the presses layout
    calibration.json    the settings, the bases' hashes, the held-out figures, each part's weights hash
    report.png          estimated against true Fz per held-out grasp; real and generated frames at three ΔF
    README.md           the table, for people

All is written under ``OUT.partial`` and renamed to OUT when complete; ``--resume`` continues a stopped run
there. Bad options or input: one line on stderr naming the flag or file, exit 2.
"""

from controltac_il.calibrate.cli import main

__all__ = ["main"]
