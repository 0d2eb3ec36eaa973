"""The interfaces a training run meets its data through, declared in the library.

An augmentation stage is ``stage(train_set) -> Augmented``: ``stage.description`` holds its settings (fixed at
construction; what a run records and a resumed run must match), ``Augmented.summary`` what it did to this
training set (counts, seconds). ``FrameTable`` is a dataset that tells each item's (episode, frame) without
reading it (``EpisodeDataset`` and ``EpisodeSubset``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from torch.utils.data import Dataset


@dataclass
class Augmented:
    """An augmented training set and what the stage did to it (JSON-serialisable counts)."""

    dataset: Dataset
    summary: dict


class AugmentStage(Protocol):
    """``train_set -> Augmented``; ``description``: the stage's settings (a JSON-serialisable dict)."""

    description: dict

    def __call__(self, train_set: Dataset) -> Augmented: ...


@runtime_checkable
class FrameTable(Protocol):
    """A dataset that tells (episode_index, frame_index) int64 (N,) of every item without reading any."""

    def frame_table(self) -> tuple[np.ndarray, np.ndarray]: ...
