"""Reference forces and contact of tactile frames: the items' force labels where they carry them, else the
force estimator (loaded on first use); and one episode's residuals, backgrounds, contact and references."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from controltac_il.augment.keys import KeyMap
from controltac_il.datasets.background import estimate_background
from controltac_il.generator.forces import VALIDATED_RANGE
from controltac_il.tactile.residual import contact_mask, to_residual


@dataclass
class EpisodeFrames:
    """One episode's tactile frames per key (copy-independent): residuals uint8 (T, H, W, 3), background
    uint8 (H, W, 3), contact bool (T,), reference force float64 (T, 3) (NaN where unknown) and where the
    background came from ("recorded" | "estimated")."""

    residuals: dict
    backgrounds: dict
    contact: dict
    reference: dict
    background_source: dict


class ReferenceForces:
    """Contact and reference force of tactile frames, per tactile key (``keys``: where labels and
    backgrounds are found in an item)."""

    def __init__(self, keys: KeyMap, contact_force: float, min_contact_area: float, estimator=None):
        self.keys = keys
        self.labelled = {k: keys.labels[k] is not None for k in keys.tactile_keys}
        self.contact_force = contact_force
        self.min_contact_area = min_contact_area
        self._estimator = estimator

    @property
    def estimator(self):
        """The force estimator (loaded on first use); a clear error when it is not available."""
        if self._estimator is None:
            try:
                from controltac_il.estimators import ForceEstimator

                self._estimator = ForceEstimator.from_pretrained()
            except (ImportError, FileNotFoundError, OSError) as exc:
                unlabelled = [k for k, v in self.labelled.items() if not v]
                raise RuntimeError(
                    f"ForceAugment: the items carry no force labels for {unlabelled}, so reference forces "
                    f"must come from a force estimator, and none could be loaded ({exc}); pass "
                    "estimator=ForceEstimator.from_pretrained(PATH) or record force labels") from exc
        return self._estimator

    def in_contact(self, residuals: np.ndarray, labels: np.ndarray | None) -> np.ndarray:
        """bool (T,): Fz >= contact_force with labels, else enough contact pixels in the residual."""
        if labels is not None:
            return labels[:, 2] >= self.contact_force
        area = contact_mask(residuals).mean(axis=(1, 2))
        return (area >= self.min_contact_area) & (area > 0)

    def label(self, item: dict, key: str) -> np.ndarray | None:
        """Force label (3,) float64 of ``key`` in one item, or None when the items carry none."""
        return self.keys.label(item, key)

    def of_frame(self, residual: np.ndarray, label: np.ndarray | None) -> np.ndarray | None:
        """Reference force (3,) float64 of one residual (H, W, 3), or None when it is not in contact."""
        if not self.in_contact(residual[None], None if label is None else label[None])[0]:
            return None
        return label if label is not None else self.estimator.predict(residual[None])[0].astype(np.float64)

    def load_episode(self, items: list, tactile_keys, episode: int) -> EpisodeFrames:
        """The EpisodeFrames of one episode's items (sorted by frame)."""
        ep = EpisodeFrames({}, {}, {}, {}, {})
        for k in tactile_keys:
            images = np.stack([self.keys.image(it, k) for it in items])
            labels = np.stack([self.keys.label(it, k) for it in items]) if self.labelled[k] else None
            bg = self.keys.background(items[0], k)
            ep.background_source[k] = "recorded" if bg is not None else "estimated"
            if bg is None:
                bg, used = estimate_background(images, labels)
                warnings.warn(f"items carry no background for {k!r}; background estimated per episode from "
                              "its own no-contact frames", stacklevel=3)
            res = to_residual(images, bg)
            touch = self.in_contact(res, labels)
            ref = np.full((len(items), 3), np.nan)
            if labels is not None:
                ref[:] = labels
            elif touch.any():
                ref[touch] = self.estimator.predict(res[touch]).astype(np.float64)
                if VALIDATED_RANGE.outside(ref[touch]).any():
                    warnings.warn(f"the force estimator reads frames of {k!r} outside the generator's validated range "
                                  f"({VALIDATED_RANGE.describe()}); those frames are kept real (summary()['skipped']). "
                                  "The shipped estimator knows the sensor model's GelSight Mini: for another sensor "
                                  "pass force_keys= (recorded labels) or an estimator= fitted to it", stacklevel=3)
            ep.residuals[k], ep.backgrounds[k], ep.contact[k], ep.reference[k] = res, bg, touch, ref
        return ep
