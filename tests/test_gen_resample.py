"""The generator's device path checked on the CPU: the resize and blur taps against OpenCV, the whole path with
the taps against the CPU's OpenCV path, and the batch sizing (``batch_size="auto"``, a batch that does not fit)."""

import cv2
import numpy as np
import pytest
import torch

from controltac_il.generator import ForceGenerator
from controltac_il.generator.batching import HEADROOM, Footprint, largest_batch, rows_per_batch
from controltac_il.generator.resample import gaussian_blur, resize
from controltac_il.tactile import HELDOUT_OBJECTS, SensorSpec, TactileSensor

RNG = np.random.default_rng(0)


@pytest.mark.parametrize("size_in", [(240, 320), (480, 640), (200, 250)])
def test_area_taps_match_opencv_where_it_shrinks(size_in):
    """Area weights are exact fractions of covered pixels; OpenCV rounds the uint8 result half to even."""
    x = RNG.integers(0, 256, (2, *size_in, 3), dtype=np.uint8)
    ours = resize(torch.from_numpy(x), (128, 160), "area", taps=True).numpy()
    theirs = np.stack([cv2.resize(im, (160, 128), interpolation=cv2.INTER_AREA) for im in x])
    assert ours.dtype == np.uint8 and ours.shape == theirs.shape
    assert np.abs(ours.astype(int) - theirs).max() <= 1 and np.mean(ours != theirs) < 0.02


def test_area_taps_are_exact_at_the_gelsight_minis_size():
    x = RNG.integers(0, 256, (2, 240, 320, 3), dtype=np.uint8)
    ours = resize(torch.from_numpy(x), (128, 160), "area", taps=True).numpy()
    np.testing.assert_array_equal(ours, np.stack([cv2.resize(im, (160, 128), interpolation=cv2.INTER_AREA)
                                                  for im in x]))


@pytest.mark.parametrize("size_out", [(240, 320), (120, 160), (256, 320), (97, 203)])
@pytest.mark.parametrize("channels", [3, 1])
def test_linear_taps_match_opencv_on_float_images(size_out, channels):
    x = RNG.normal(0, 40, (2, 128, 160, channels)).astype(np.float32)
    ours = resize(torch.from_numpy(x), size_out, "linear", taps=True).numpy()
    theirs = resize(torch.from_numpy(x), size_out, "linear").numpy()  # OpenCV on the CPU
    assert ours.shape == theirs.shape == (2, *size_out, channels)
    np.testing.assert_allclose(ours, theirs, atol=1e-3)


@pytest.mark.parametrize("size_in", [(120, 160), (100, 130), (64, 80)])
def test_area_taps_match_opencv_where_it_grows(size_in):
    """A frame smaller than the model's size: OpenCV's INTER_AREA upward is a sharp blend of neighbours."""
    x = RNG.normal(0, 40, (2, *size_in, 3)).astype(np.float32)
    ours = resize(torch.from_numpy(x), (128, 160), "area", taps=True).numpy()
    theirs = np.stack([cv2.resize(im, (160, 128), interpolation=cv2.INTER_AREA) for im in x])
    np.testing.assert_allclose(ours, theirs, atol=1e-3)


def test_gaussian_taps_match_opencv_with_its_reflect_101_border():
    x = RNG.normal(0, 40, (2, 128, 160)).astype(np.float32)
    x[:, 0, :] = 500.0  # a bright edge row: the border rule decides the first rows
    ours = gaussian_blur(torch.from_numpy(x), 2.0, taps=True).numpy()
    np.testing.assert_allclose(ours, np.stack([cv2.GaussianBlur(im, (0, 0), 2.0) for im in x]), atol=1e-3)
    for sigma, taps in ((0.0, True), (0.0, False), (float("nan"), True)):
        with pytest.raises(ValueError, match=r"^sigma: expected a finite number of pixels > 0"):
            gaussian_blur(torch.from_numpy(x), sigma, taps=taps)


@pytest.fixture(scope="module")
def presses():
    sensor = TactileSensor(SensorSpec.gelsight_mini())
    res = np.stack([sensor.press(HELDOUT_OBJECTS[k], (0.0, 0.0, 0.0), (0.0, 0.0, 3.0 + k), noise_seed=k).residual
                    for k in range(4)])  # one chunk
    return res, np.tile(np.float32([[0.0, 0.0, 2.0]]), (len(res), 1))


def test_the_device_path_on_cpu_tensors_gives_the_cpu_paths_bytes_to_one_grey_level(presses):
    """The accelerator's path (taps) run on the CPU against the CPU's (OpenCV) at the GelSight Mini's 240×320:
    the two differ only by float rounding, so at most one grey level on a few values in a hundred thousand."""
    refs, df = presses
    cpu = ForceGenerator.from_pretrained().generate(refs, df, seed=0)
    device_path = ForceGenerator.from_pretrained(resample_taps=True)
    taps = device_path.generate(refs, df, seed=0)
    diff = np.abs(cpu.astype(int) - taps)
    assert diff.max() <= 1 and np.mean(diff > 0) < 1e-4, (diff.max(), np.mean(diff > 0))
    np.testing.assert_array_equal(device_path.generate(refs[2:3], df[2:3], seed=0)[0], taps[2])  # alone


def test_largest_batch_is_whole_chunks_within_the_headroom():
    fp = Footprint(fixed=1000, per_row=100)
    free = int((1000 + 130 * 100) / HEADROOM)  # room for 130 rows: 128 in chunks of 4, 96 in chunks of 32
    assert largest_batch(fp, free, 4) == 128 and largest_batch(fp, free, 32) == 128
    assert largest_batch(fp, free - 300, 32) == 96
    with pytest.raises(ValueError, match=r"^batch_size: not even one chunk of 256 rows fits"):
        largest_batch(fp, free, 256)
    assert rows_per_batch("auto", fp, free, 4, rows=10) == 12  # never more than the rows asked for
    assert rows_per_batch(5, fp, free, 4, rows=100) == 8  # an int batch rounds up to whole chunks


def test_a_batch_that_does_not_fit_is_refused_in_one_line_and_auto_gives_the_same_bytes(presses, monkeypatch):
    """The device's free memory is read through ``pipeline.free_bytes``; here it is set, as a clock would be."""
    from controltac_il.generator import pipeline

    refs, df = presses
    gen = ForceGenerator.from_pretrained()
    fp = gen.footprint(refs.shape[1:3])
    monkeypatch.setattr(pipeline, "free_bytes", lambda device: int(fp.bytes(4) / HEADROOM) + 1)  # one chunk
    with pytest.raises(ValueError, match=r"^batch_size 8 does not fit: it needs [\d.]+ GiB and [\d.]+ GiB is free "
                                         r"\(80% usable\); batch_size='auto' fits 4$"):
        gen.generate(np.repeat(refs, 2, 0), np.repeat(df, 2, 0), batch_size=8)  # two chunks at once
    np.testing.assert_array_equal(gen.generate(refs, df, seed=1, batch_size="auto"),
                                  gen.generate(refs, df, seed=1, batch_size=4))
    monkeypatch.setattr(pipeline, "free_bytes", lambda device: fp.bytes(1))
    with pytest.raises(ValueError, match=r"^batch_size: not even one chunk of 4 rows fits"):
        gen.generate(refs, df, batch_size="auto")


def test_batch_size_auto_is_a_config_setting_and_a_flag_value():
    from argparse import ArgumentTypeError

    from controltac_il.augment.config import ForceAugmentConfig
    from controltac_il.config import parse_batch_size

    assert parse_batch_size("auto") == "auto" and parse_batch_size("48") == 48
    for bad in ("0", "-3", "big", "2.5"):
        with pytest.raises(ArgumentTypeError, match=f"^expected an int >= 1 or 'auto', got '{bad}'$"):
            parse_batch_size(bad)
    assert ForceAugmentConfig(batch_size="auto").batch_size == "auto"
    with pytest.raises(ValueError, match=r"batch_size: expected an int >= 1 or 'auto' \(got 'big'\)"):
        ForceAugmentConfig(batch_size="big")
