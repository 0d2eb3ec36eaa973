"""Training of the generator, stage 1 (force control) and stage 2 (the pose adapter), behind one command line:
``python -m controltac_il.generator.training stage1 ...`` / ``... stage2 ...``.

Modules: ``cli`` (the command line: options, checks, the run folder's guard), ``config`` (the runs' arguments,
provenance and model card), ``stage1`` (the stage-1 job: autoencoder, latents, DiT of a run), ``stage2`` (the
stage-2 job: the pose adapter over a frozen stage 1), ``data`` (stage 1's pairs of a sensor-model dataset),
``pose_data`` (stage 2's scenes and cross-pose pairs), ``objectives`` (the denoiser's objective and EMA, both stages
alike), ``validation`` (a run's own held-out objects and the error it ships by), ``finetune`` (a generator
fine-tuned on one sensor's presses, for ``controltac_il.calibrate``).
"""
