"""``PhotometricAugment``: K extra copies of every episode with the tactile images photometrically jittered.

The control for ForceAugment: what a LeRobot user would do with ``image_transforms``
(brightness, contrast, blur, noise on one image tensor, knowing nothing of force or background),
made deterministic and per trajectory like ForceAugment, so that "more varied pixels" and "force-
conditioned pixels" can be compared at the same number of copies.

Copy 0 is the real data; copy k of episode e draws one brightness gain, contrast gain and blur sigma
from (seed, e, k) and per-frame pixel noise from (seed, e, k, frame). Only ``observation.tactile.*``
images change; everything else (backgrounds included) is returned as read.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset

from controltac_il.datasets.stage import Augmented
from controltac_il.streams import HDF5_TACTILE


@dataclass(frozen=True)
class PhotometricJitter:
    """Ranges of the jitter (uniform draws). Gains multiply; contrast scales about the image mean.

    brightness: (low, high) gain on all pixels. contrast: (low, high) gain of the deviation from the
    image's mean grey. blur_sigma_px: (low, high) Gaussian blur sigma in pixels (0 = none).
    noise_std: (low, high) std of per-frame Gaussian pixel noise, grey levels (0-255 scale).
    """

    brightness: tuple[float, float] = (0.8, 1.2)
    contrast: tuple[float, float] = (0.8, 1.2)
    blur_sigma_px: tuple[float, float] = (0.0, 1.0)
    noise_std: tuple[float, float] = (0.0, 3.0)

    def __post_init__(self):
        for name, value in asdict(self).items():
            lo, hi = value
            if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi):
                raise ValueError(f"PhotometricJitter.{name} must be (low, high) with 0 <= low <= high, got {value!r}")


def jitter_image(image: np.ndarray, gain: float, contrast: float, sigma: float, noise: np.ndarray) -> np.ndarray:
    """uint8 (H, W, 3) -> uint8 (H, W, 3): contrast about the mean, brightness gain, blur, + noise."""
    x = image.astype(np.float32)
    mean = x.mean()
    x = (mean + (x - mean) * contrast) * gain
    if sigma > 0:
        x = cv2.GaussianBlur(x, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)
    return np.clip(np.rint(x + noise), 0, 255).astype(np.uint8)


class PhotometricAugment(Dataset):
    """``len = (copies + 1) * len(dataset)``; index ``k * len(dataset) + i`` is copy k of item i.

    dataset: map-style dataset of EpisodeDataset items (``episode_index``, ``frame_index`` and
        ``observation.tactile.<s>`` uint8 (3, H, W) tensors).
    copies: jittered copies per episode (>= 1). seed: seeds every draw. jitter: the ranges.
    """

    def __init__(self, dataset, copies: int, seed: int = 0, jitter: PhotometricJitter | None = None):
        if not isinstance(copies, int) or copies < 1:
            raise ValueError(f"copies must be an int >= 1, got {copies!r}")
        self.dataset, self.copies, self.seed = dataset, copies, int(seed)
        self.jitter = jitter or PhotometricJitter()
        self.description = {"kind": "image", "copies": copies, "seed": self.seed,
                            **{k: list(v) for k, v in asdict(self.jitter).items()}}  # as JSON reads it back

    def __len__(self) -> int:
        return (self.copies + 1) * len(self.dataset)

    def __getitem__(self, index: int) -> dict:
        n = len(self.dataset)
        if not -len(self) <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} items")
        copy, i = divmod(index % len(self), n)
        item = self.dataset[i]
        if copy == 0:
            return item
        episode, frame = int(item["episode_index"]), int(item["frame_index"])
        j = self.jitter
        traj = np.random.default_rng([self.seed, episode, copy])
        gain, contrast = traj.uniform(*j.brightness), traj.uniform(*j.contrast)
        sigma, noise_std = traj.uniform(*j.blur_sigma_px), traj.uniform(*j.noise_std)
        frame_rng = np.random.default_rng([self.seed, episode, copy, frame])
        out = dict(item)
        for key in sorted(k for k in item if k.startswith(HDF5_TACTILE)):
            image = item[key].permute(1, 2, 0).numpy()
            noise = frame_rng.normal(0.0, noise_std, image.shape).astype(np.float32)
            out[key] = torch.from_numpy(jitter_image(image, gain, contrast, sigma, noise)).permute(2, 0, 1)
        return out


class PhotometricAugmentStage:
    """``train_set -> Augmented(PhotometricAugment(train_set))`` (``controltac_il.datasets.stage``)."""

    def __init__(self, copies: int, seed: int = 0, jitter: PhotometricJitter | None = None):
        self.copies, self.seed, self.jitter = copies, seed, jitter or PhotometricJitter()
        self.description = PhotometricAugment([], copies, seed, self.jitter).description

    def __call__(self, train_set) -> Augmented:
        aug = PhotometricAugment(train_set, self.copies, self.seed, self.jitter)
        return Augmented(aug, {"real_items": len(train_set), "jittered_items": len(aug) - len(train_set)})
