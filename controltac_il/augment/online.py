"""Online mode: the tactile images of one item of an augmented copy, generated on access."""

from __future__ import annotations

import numpy as np

from controltac_il.augment.config import ForceAugmentConfig
from controltac_il.augment.draws import copy_offset, frame_jitter, noise_seed, requested_target, status_of
from controltac_il.augment.items import background_key, replace_image, to_hwc_uint8
from controltac_il.augment.records import STATUS, FrameOutcome, KeyOutcome
from controltac_il.augment.reference import ReferenceForces
from controltac_il.tactile.residual import from_residual, to_residual


def check_online_items(probe: dict, tactile_keys) -> None:
    """Online mode needs each item's no-contact background (mode 'cache' estimates it per episode)."""
    missing = [k for k in tactile_keys if background_key(k) not in probe]
    if missing:
        raise ValueError(
            f"tactile_keys: items carry no {background_key(missing[0])!r}; online mode needs the "
            "no-contact background in each item (use mode='cache', which estimates it per episode)")


def generate_item(item: dict, episode: int, copy: int, frame: int, *, generator, config: ForceAugmentConfig,
                  steps: int, tactile_keys, references: ReferenceForces) -> tuple[dict, FrameOutcome]:
    """Replace the tactile images of ``item`` (frame ``frame`` of copy ``copy`` of ``episode``) that the
    generator redraws; returns the item and what was done per key."""
    cfg = config
    offset = copy_offset(cfg.seed, episode, copy, cfg.offset_range)
    jitter = frame_jitter(cfg.seed, episode, copy, frame, cfg.jitter)
    outcomes = []
    for j, k in enumerate(tactile_keys):
        background = to_hwc_uint8(item[background_key(k)], background_key(k))
        residual = to_residual(to_hwc_uint8(item[k], k), background)
        ref = references.of_frame(residual, references.label(item, k))
        if ref is None:
            outcomes.append(KeyOutcome(STATUS["no_contact"]))
            continue
        res = generator.generate_at(residual[None], ref[None], requested_target(ref, offset + jitter)[None],
                                    steps=steps, seed=[noise_seed(cfg.seed, episode, copy, frame, j)],
                                    batch_size=cfg.batch_size, out_of_range=cfg.out_of_range,
                                    reference_out_of_range="skip")  # as the cache writer: keep it real
        target, status = res.decision.target[0], status_of(res.decision, 0)
        if status != STATUS["skipped"]:
            replace_image(item, k, from_residual(res.residuals[0], background), target)
        outcomes.append(KeyOutcome(status, reference=ref, target=target))
    return item, FrameOutcome(offset, jitter, tuple(outcomes))
