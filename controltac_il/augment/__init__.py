"""ForceAugment: force-controlled tactile augmentation of an imitation-learning dataset.

    from controltac_il.augment import ForceAugment
    from controltac_il.datasets import EpisodeDataset
    dataset = ForceAugment(EpisodeDataset("demos/"), copies=4, cache_dir="cache/")  # then train as before

Index ``i`` of the wrapper is copy ``i // N`` of item ``i % N`` of the wrapped dataset (N items).
Copy 0 is the real data. Copy k >= 1 of episode e is a virtual trajectory: one normal-force offset
drawn from U[offset_range] for the whole copy, plus one jitter value per frame, added to the
reference force of every frame in contact; the generator redraws the tactile image at that target.
Every draw (offset, jitter, generator noise) is a pure function of (seed, episode, copy, frame), so
the virtual trajectory is the same in every worker, epoch, process and sampling order.

Items are the wrapped items, with only the regenerated tactile images (and their force labels, set
to the target force) replaced, plus one float32 tensor ``augment`` (K, 10) saying what was done, one
row per tactile key (order of ``ForceAugment.tactile_keys``), columns ``AUGMENT_FIELDS``::

    copy, offset, jitter          copy index (0 = real), the copy's normal-force offset and the frame's
                                  jitter, N (0 for copy 0)
    status                        STATUS code of that key's image (real, no_contact, regenerated, ...)
    ref_fx, ref_fy, ref_fz        reference force, N (NaN where not known or not needed)
    target_fx, target_fy, target_fz  force the returned image shows, N (NaN where not known)

One tensor rather than ten keeps the DataLoader fast (every tensor of a batch crosses between
processes on its own). ``ForceAugment.info(item_or_batch)`` names the columns for logging.

``mode="cache"`` generates every augmented frame once (batched) into ``cache_dir`` and reads it back;
``mode="online"`` generates on access. Both give the same bytes whatever the batch size and the shuffling,
when torch runs the same number of intra-op threads (the generator's ``numerics()``, which the cache records:
a cache built with another thread count is another cache). ``python -m controltac_il.augment --help`` builds a
cache.

Any map-style dataset of dict items works (LeRobot convention, without importing LeRobot): a tactile stream
recorded as a camera is named in ``tactile_keys``; force labels and backgrounds are optional and read only
under ``force_keys`` / ``background_keys`` or our layout's naming rule (module ``keys``); time windows of
``delta_timestamps`` are augmented frame by frame.

Modules: ``config`` (ForceAugmentConfig), ``keys`` (which item keys are read), ``items`` (item adapters),
``reference`` (contact and reference forces), ``draws`` (offset, jitter, noise seeds), ``records`` (status codes, the ``augment`` tensor),
``online`` (generation on access), ``provenance`` / ``writer`` / ``reader`` (the sharded cache), ``dataset``
(``ForceAugment``), ``stage`` (``ForceAugmentStage``, a training run's stage), ``cli`` (``python -m controltac_il.augment``). The generator alone decides what
happens to a target outside its validated range (``controltac_il.generator.forces``).
"""

from controltac_il.lazy import exports

_EXPORTS = {"main": "controltac_il.augment.cli",
            **dict.fromkeys(("BUILD", "MODES", "OUT_OF_RANGE", "ForceAugmentConfig"), "controltac_il.augment.config"),
            "ForceAugment": "controltac_il.augment.dataset",
            **dict.fromkeys(("copy_offset", "frame_jitter", "noise_seed"), "controltac_il.augment.draws"),
            **dict.fromkeys(("CACHE_FORMAT", "FrameRecord", "StaleCacheError"), "controltac_il.augment.provenance"),
            **dict.fromkeys(("AUGMENT_FIELDS", "STATUS"), "controltac_il.augment.records"),
            "ForceAugmentStage": "controltac_il.augment.stage"}
__getattr__, __dir__ = exports(__name__, _EXPORTS)
__all__ = list(_EXPORTS)
