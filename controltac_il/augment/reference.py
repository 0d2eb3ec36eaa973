"""Reference forces and contact of tactile frames: the items' force labels where they carry them, else the
force estimator (loaded on first use); and one episode's residuals, backgrounds, contact and references."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from controltac_il.augment.keys import KeyMap
from controltac_il.datasets.background import estimate_background
from controltac_il.datasets.checks import check_force_labels
from controltac_il.generator.forces import NOMINAL_FZ, VALIDATED_RANGE



def working_reference(estimates: np.ndarray, policy: str) -> np.ndarray:
    """Reference forces (N, 3) N the generator is asked from, for estimates (N, 3) N: those inside the validated
    range as they are; those outside it (not a force the model was validated on, and an estimator's reading of a
    sensor it does not know) under ``policy``: "nominal" (0, 0, NOMINAL_FZ), "clip" (0, 0, Fz clipped into the
    range), "skip" unchanged (the generator keeps the frame real). Shear is dropped with them: ForceAugment's
    offsets are normal-only, so it would only matter where a target is clamped."""
    out = np.array(estimates, np.float64)
    bad = VALIDATED_RANGE.outside(out).any(axis=-1)
    if policy == "skip" or not bad.any():
        return out
    fz = np.full(int(bad.sum()), NOMINAL_FZ) if policy == "nominal" else np.clip(out[bad, 2], *VALIDATED_RANGE.fz)
    out[bad] = np.stack([np.zeros_like(fz), np.zeros_like(fz), fz], axis=-1)
    return out
from controltac_il.tactile.residual import blank, contact_mask, to_residual


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


class NominalEstimator:
    """Reads every frame as the nominal reference (0, 0, NOMINAL_FZ) N: a calibration bundle's stand-in for an
    estimator that does not beat the constant baseline on held-out grasps (``calibration.json``)."""

    checkpoint_hash = "nominal"

    def predict(self, residuals, batch_size: int = 256, gate: bool = True) -> np.ndarray:
        return np.tile(np.array([0.0, 0.0, NOMINAL_FZ], np.float32), (len(residuals), 1))


def bundle_estimator(path):
    """The estimator of the calibration bundle at ``path`` (``python -m controltac_il.calibrate``): its calibrated
    one, or NominalEstimator (with a one-line warning) where the bundle says it does not beat the constant; None
    where ``path`` holds no bundle's estimator part (a plain generator checkpoint or a shipped name)."""
    import json
    from pathlib import Path

    from controltac_il.estimators import ForceEstimator
    from controltac_il.estimators.estimator import BUNDLE_PART

    if not (Path(path) / BUNDLE_PART).is_dir():
        return None
    record = Path(path) / "calibration.json"
    try:
        use = json.loads(record.read_text())["estimator"].get("use_estimator", True) if record.is_file() else True
    except (ValueError, KeyError, TypeError, AttributeError) as exc:  # a record no calibrate wrote
        raise ValueError(f"{record}: not a calibration record (no estimator decision: {type(exc).__name__} "
                         f"{exc}); recalibrate the sensor") from None
    if not use:
        warnings.warn(f"{path}: its calibrated estimator does not beat the constant baseline on held-out grasps; "
                      f"unlabelled frames take the nominal reference (0, 0, {NOMINAL_FZ:g}) N", stacklevel=3)
        return NominalEstimator()
    return ForceEstimator.from_pretrained(path)


def estimator_at(path):
    """The force estimator a checkpoint folder or a calibration bundle gives (a bundle's decision kept:
    ``bundle_estimator``)."""
    from controltac_il.estimators import ForceEstimator

    return bundle_estimator(path) or ForceEstimator.from_pretrained(path)


class ReferenceForces:
    """Contact and reference force of tactile frames, per tactile key (``keys``: where labels and
    backgrounds are found in an item)."""

    def __init__(self, keys: KeyMap, contact_force: float, min_contact_area: float, estimator=None,
                 estimated_reference: str = "nominal"):
        self.keys, self.estimated_reference, self._warned = keys, estimated_reference, False
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

    def in_contact(self, images: np.ndarray, residuals: np.ndarray, labels: np.ndarray | None) -> np.ndarray:
        """bool (T,) for images and their residuals (T, H, W, 3): Fz >= contact_force with labels, else enough
        contact pixels in the residual; never a blank image (every value 0 or 255), which is kept real."""
        empty = blank(images)
        if empty.any():
            warnings.warn(f"{int(empty.sum())} tactile frame(s) have every value 0 or 255 (a dark, overexposed or "
                          "dropped camera frame): kept real, never a reference", stacklevel=3)
        if labels is not None:
            return (labels[:, 2] >= self.contact_force) & ~empty
        area = contact_mask(residuals).mean(axis=(1, 2))
        return (area >= self.min_contact_area) & (area > 0) & ~empty

    def label(self, item: dict, key: str) -> np.ndarray | None:
        """Force label (3,) float64 of ``key`` in one item, or None when the items carry none."""
        return self.keys.label(item, key)

    def of_frame(self, image: np.ndarray, residual: np.ndarray, label: np.ndarray | None) -> np.ndarray | None:
        """Reference force (3,) float64 of one image and its residual (H, W, 3), or None when it is not in
        contact."""
        if not self.in_contact(image[None], residual[None], None if label is None else label[None])[0]:
            return None
        return label if label is not None else self.estimator.predict(residual[None])[0].astype(np.float64)

    def _warn_outside(self, key: str, estimates: np.ndarray) -> None:
        """Say once what is done with estimates outside the validated range, and why."""
        bad = VALIDATED_RANGE.outside(estimates).any(axis=-1)
        if self._warned or not bad.any():
            return
        self._warned = True
        done = {"skip": "those frames are kept real (summary()['skipped'])",
                "nominal": f"those frames are augmented from the working reference (0, 0, {NOMINAL_FZ:g}) N",
                "clip": "those frames are augmented from their Fz clipped into the range, without shear"}
        warnings.warn(f"the force estimator reads {int(bad.sum())} of {len(bad)} contact frames of {key!r} (first "
                      f"episode read) outside the generator's validated range ({VALIDATED_RANGE.describe()}), e.g. "
                      f"{np.round(estimates[np.flatnonzero(bad)[0]], 1).tolist()} N; estimated_reference="
                      f"{self.estimated_reference!r}: {done[self.estimated_reference]}. Only ΔF conditions the "
                      "generator; for force-labelled targets pass force_keys= or an estimator= fitted to this sensor",
                      stacklevel=4)

    def load_episode(self, items: list, tactile_keys, episode: int) -> EpisodeFrames:
        """The EpisodeFrames of one episode's items (sorted by frame)."""
        ep = EpisodeFrames({}, {}, {}, {}, {})
        for k in tactile_keys:
            frames = [self.keys.image(it, k) for it in items]
            odd = [i for i, f in enumerate(frames) if f.shape != frames[0].shape]
            if odd:
                at = int(items[odd[0]].get("frame_index", odd[0]))
                raise ValueError(f"{k}: episode {episode}'s frame {at} is {frames[odd[0]].shape[:2]}, its first "
                                 f"{frames[0].shape[:2]}; every tactile frame of an episode needs one size")
            images = np.stack(frames)
            labels = np.stack([self.keys.label(it, k) for it in items]) if self.labelled[k] else None
            if labels is not None:  # in N, Fz > 0 pressing: else every copy is silently no-contact or skipped
                check_force_labels(f"{self.keys.labels[k]} (episode {episode})", labels)
            bg = self.keys.background(items[0], k)
            ep.background_source[k] = "recorded" if bg is not None else "estimated"
            if bg is None:
                bg, used = estimate_background(images, labels)
                warnings.warn(f"items carry no background for {k!r}; background estimated per episode from "
                              "its own no-contact frames (background_images= gives a recorded one)", stacklevel=3)
            res = to_residual(images, bg)
            touch = self.in_contact(images, res, labels)
            ref = np.full((len(items), 3), np.nan)
            if labels is not None:
                ref[:] = labels
            elif touch.any():
                estimates = self.estimator.predict(res[touch]).astype(np.float64)
                ref[touch] = working_reference(estimates, self.estimated_reference)
                self._warn_outside(k, estimates)
            ep.residuals[k], ep.backgrounds[k], ep.contact[k], ep.reference[k] = res, bg, touch, ref
        return ep
