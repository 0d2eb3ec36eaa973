"""PhotometricAugment: the image-jitter control for ForceAugment (same copies, no force conditioning)."""

import numpy as np
import pytest
import torch

from controltac_il.datasets.photometric import PhotometricAugment, PhotometricAugmentStage, PhotometricJitter, jitter_image


class Items(torch.utils.data.Dataset):
    """Two episodes of three frames with one tactile stream, its background and an action."""

    def __init__(self):
        rng = np.random.default_rng(0)
        self.items = []
        for e in range(2):
            for t in range(3):
                self.items.append({
                    "episode_index": e, "frame_index": t,
                    "observation.tactile.left": torch.from_numpy(rng.integers(40, 200, (3, 12, 16), dtype=np.uint8)),
                    "observation.tactile_background.left": torch.full((3, 12, 16), 100, dtype=torch.uint8),
                    "observation.images.wrist": torch.from_numpy(rng.integers(0, 255, (3, 8, 8), dtype=np.uint8)),
                    "action": torch.arange(10, dtype=torch.float32).reshape(2, 5) + e,
                })

    def __len__(self):
        return len(self.items)

    def __getitem__(self, i):
        return self.items[i]


def test_copy_zero_is_the_real_data_and_copies_change_only_tactile_images():
    base = Items()
    aug = PhotometricAugment(base, copies=2, seed=3)
    assert len(aug) == 18
    for i in range(6):
        assert aug[i] is base[i]
        for k in (1, 2):
            item = aug[k * 6 + i]
            for key, value in base[i].items():
                if key == "observation.tactile.left":
                    assert item[key].dtype == torch.uint8 and item[key].shape == value.shape
                    assert not torch.equal(item[key], value)
                elif torch.is_tensor(value):
                    assert torch.equal(item[key], value), key
                else:
                    assert item[key] == value


def test_draws_are_pure_functions_of_seed_episode_copy_and_frame():
    a, b = PhotometricAugment(Items(), 2, seed=3), PhotometricAugment(Items(), 2, seed=3)
    for i in range(6, 18):
        assert torch.equal(a[i]["observation.tactile.left"], b[i]["observation.tactile.left"])
    other = PhotometricAugment(Items(), 2, seed=4)
    assert not torch.equal(a[7]["observation.tactile.left"], other[7]["observation.tactile.left"])
    assert not torch.equal(a[7]["observation.tactile.left"], a[13]["observation.tactile.left"])  # copy 1 vs 2
    assert torch.equal(a[-1]["observation.tactile.left"], a[17]["observation.tactile.left"])
    with pytest.raises(IndexError):
        a[18]


def test_jitter_image_semantics():
    img = np.random.default_rng(1).integers(50, 200, (10, 12, 3), dtype=np.uint8)
    zero = np.zeros(img.shape, np.float32)
    assert np.array_equal(jitter_image(img, 1.0, 1.0, 0.0, zero), img)  # identity
    bright = jitter_image(img, 1.2, 1.0, 0.0, zero).astype(int)
    assert np.array_equal(bright, np.clip(np.rint(img * 1.2), 0, 255))
    flat = jitter_image(img, 1.0, 0.0, 0.0, zero)
    assert flat.max() - flat.min() <= 1  # no contrast: every pixel at the mean
    blurred = jitter_image(img, 1.0, 1.0, 2.0, zero).astype(float)
    assert blurred.std() < img.std()
    assert jitter_image(np.full(img.shape, 250, np.uint8), 1.2, 1.0, 0.0, zero).max() == 255  # clipped, not wrapped


def test_bad_settings_name_the_field():
    with pytest.raises(ValueError, match="copies"):
        PhotometricAugment(Items(), 0)
    with pytest.raises(ValueError, match="PhotometricJitter.noise_std"):
        PhotometricJitter(noise_std=(3.0, 1.0))
    with pytest.raises(ValueError, match="PhotometricJitter.brightness"):
        PhotometricJitter(brightness=(float("nan"), 1.0))


def test_stage_describes_itself_for_the_training_run():
    stage = PhotometricAugmentStage(2, seed=1)
    assert stage.description["kind"] == "image" and stage.description["copies"] == 2
    assert stage.description["brightness"] == [0.8, 1.2]
    out = stage(Items())
    assert len(out.dataset) == 18 and out.summary == {"real_items": 6, "jittered_items": 12}
