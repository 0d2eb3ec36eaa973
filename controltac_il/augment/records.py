"""What was done to an item: per tactile key status codes and the ``augment`` (K, 10) tensor of each item."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

# Per (frame, tactile key) outcome of an augmented copy.
STATUS = {"real": 0, "no_contact": 1, "regenerated": 2, "clamped": 3, "skipped": 4}
STATUS_NAME = {v: k for k, v in STATUS.items()}
AUGMENT_FIELDS = ("copy", "offset", "jitter", "status", "ref_fx", "ref_fy", "ref_fz",
                  "target_fx", "target_fy", "target_fz")
GENERATED = (STATUS["regenerated"], STATUS["clamped"])


@dataclass(frozen=True)
class KeyOutcome:
    """One tactile key of one frame: STATUS code, position of its image in the chunk's file (-1: none,
    cache only), reference and target force (3,) N or None where not known / not needed."""

    status: int
    row: int = -1
    reference: np.ndarray | None = None
    target: np.ndarray | None = None

    @property
    def generated(self) -> bool:
        return self.status in GENERATED


@dataclass(frozen=True)
class FrameOutcome:
    """One frame of a copy: the copy's offset, the frame's jitter (N) and one KeyOutcome per tactile key."""

    offset: float
    jitter: float
    keys: tuple[KeyOutcome, ...]


def annotate(item: dict, copy: int, outcome: FrameOutcome, tactile_keys, labels: dict) -> dict:
    """Add ``augment`` (K, 10) float32 to ``item``; labels: key -> the item's force label (3,) of that key, or None."""
    rows = np.full((len(tactile_keys), len(AUGMENT_FIELDS)), np.nan, np.float32)
    rows[:, :3] = copy, outcome.offset, outcome.jitter
    for i, (k, rec) in enumerate(zip(tactile_keys, outcome.keys)):
        ref = rec.reference
        if ref is None and labels.get(k) is not None:
            ref = labels[k]
        rows[i, 3] = rec.status
        if ref is not None:
            rows[i, 4:7] = ref
        shown = rec.target if rec.generated else ref
        if shown is not None:
            rows[i, 7:10] = shown
    item["augment"] = torch.from_numpy(rows)
    return item


def info(item: dict, tactile_keys) -> dict:
    """Named columns of ``item["augment"]`` (an item's (K, 10) or a batch's (B, K, 10))."""
    a = item.get("augment") if isinstance(item, dict) else None
    if a is None:
        raise ValueError("item: has no 'augment' record; pass an item (or a batch) of this ForceAugment")
    status = a[..., 3].long()
    out = {"copy": a[..., 0, 0].long(), "offset": a[..., 0, 1], "jitter": a[..., 0, 2],
           "augmented": ((status == STATUS["regenerated"]) | (status == STATUS["clamped"])).any(-1)}
    for i, k in enumerate(tactile_keys):
        out[f"status.{k}"] = status[..., i]
        out[f"reference_force.{k}"] = a[..., i, 4:7]
        out[f"target_force.{k}"] = a[..., i, 7:10]
    return out
