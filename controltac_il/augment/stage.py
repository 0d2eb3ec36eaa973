"""The ForceAugment stage of a training run (``controltac_il.datasets.stage``): ``train_set -> K generated copies``."""

from __future__ import annotations

import time
from pathlib import Path

from torch.utils.data import Subset

from controltac_il.augment.config import ForceAugmentConfig
from controltac_il.augment.dataset import ForceAugment
from controltac_il.datasets.stage import Augmented
from controltac_il.generator.checkpoint import checkpoint_hash
from controltac_il.generator.shipped import locate_checkpoint


class ForceAugmentStage:
    """K generated copies of every training episode, as ``train_act.py --augment force`` adds them.

    The cache holds ``max_copies`` copies; asking for fewer uses the first K of them (every draw is a
    pure function of (seed, episode, copy, frame), so copy k is the same whatever K is).
    settings: other ``ForceAugmentConfig`` fields (e.g. ``offset_range``, ``out_of_range``); the
    description names only those that differ from the defaults (older runs stay comparable).
    """

    def __init__(self, copies: int, generator: str | Path | None = None, seed: int = 0,
                 max_copies: int | None = None, steps: int | None = None, cache_dir: str | Path | None = None,
                 **settings):
        if not 1 <= copies <= 9:
            raise ValueError(f"copies must be in 1..9 (the paper's range), got {copies}")
        self.copies, self.generator, self.seed, self.steps = copies, generator, seed, steps
        self.max_copies = max(copies, max_copies or copies)
        self.cache_dir = cache_dir
        ForceAugmentConfig(**settings)  # a bad field fails here, naming it, before any work
        defaults = ForceAugmentConfig()
        self.settings = {k: v for k, v in settings.items() if getattr(ForceAugmentConfig(**{k: v}), k) != getattr(defaults, k)}
        self.description = {"kind": "force", "copies": copies, "generator": str(generator or "shipped"),
                            "generator_hash": checkpoint_hash(locate_checkpoint(generator)),
                            "seed": seed, "steps": steps,
                            **{k: list(v) if isinstance(v, tuple) else v for k, v in self.settings.items()}}

    def __call__(self, train_set) -> Augmented:
        """ForceAugment over ``train_set`` (its first ``copies`` copies); the summary counts those copies' frames."""
        t0 = time.perf_counter()  # the path, not a loaded model: a calibration bundle brings its estimator (or declines)
        aug = ForceAugment(train_set, self.generator, copies=self.max_copies, seed=self.seed, steps=self.steps,
                           cache_dir=self.cache_dir, **self.settings)
        summary = {**aug.summary(self.copies), "seconds": time.perf_counter() - t0}
        n = len(train_set)
        return Augmented(aug if self.copies == self.max_copies else Subset(aug, range((self.copies + 1) * n)), summary)
