"""The shipped force-estimator checkpoint reads sensor-model frames: no contact ≈ 0 N, presses ≈ their force."""

import os

import numpy as np
import pytest

from controltac_il.estimators import ForceEstimator
from controltac_il.estimators.estimator import DEFAULT_CHECKPOINT
from controltac_il.tactile import HELDOUT_OBJECTS, TRAIN_OBJECTS, SensorSpec, TactileSensor

CKPT = os.environ.get("CONTROLTAC_TEST_ESTIMATOR") or None  # lets a new checkpoint be tested before shipping


@pytest.fixture(scope="module")
def est():
    return ForceEstimator.from_pretrained(CKPT)


@pytest.fixture(scope="module")
def sensor():
    return TactileSensor(SensorSpec.gelsight_mini(), seed=0)


def test_shipped_checkpoint_is_small_with_card():
    files = {p.name: p.stat().st_size for p in DEFAULT_CHECKPOINT.iterdir()}
    assert {"model.safetensors", "config.json", "README.md"} <= set(files)
    assert sum(files.values()) < 5 * 2**20


def test_no_contact_frames_read_about_zero(est, sensor):
    blank = np.zeros((sensor.spec.height, sensor.spec.width), np.float32)
    frames = np.stack([sensor.render_penetration(blank, noise_seed=s) for s in range(8)])
    residuals = frames.astype(np.int16) - sensor.background + 127
    residuals = np.clip(residuals, 0, 255).astype(np.uint8)
    assert not est.contact_visible(residuals).any()
    assert (est.predict(residuals) == 0).all()


def test_presses_of_training_objects_read_close_to_their_force(est, sensor):
    rng = np.random.default_rng(123)
    res, true = [], []
    for obj in TRAIN_OBJECTS:
        for _ in range(3):
            pose = (rng.uniform(-3, 3), rng.uniform(-2, 2), rng.uniform(0, np.pi))
            force = (rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(1, 10))
            c = sensor.press(obj, pose, force, noise_seed=int(rng.integers(1 << 30)))
            res.append(c.residual)
            true.append(c.force)
    pred, true = est.predict(np.stack(res)), np.asarray(true)
    mae = np.abs(pred - true).mean(axis=0)
    baseline = np.abs(true - true.mean(axis=0)).mean(axis=0)  # always reading the mean force
    assert (mae < 0.5 * baseline).all(), (mae, baseline)
    assert mae[2] < 0.8, mae


def test_normal_force_reading_grows_with_force(est, sensor):
    for obj in ("big_sphere", "cross"):
        res = [sensor.press(obj, (0.5, -0.5, 0.3), (0.0, 0.0, fz), noise_seed=1).residual for fz in (1.5, 4.5, 9.0)]
        fz = est.predict(np.stack(res))[:, 2]
        assert fz[0] < fz[1] < fz[2], (obj, fz)


def test_shear_sign_is_read(est, sensor):
    res = [sensor.press("big_sphere", (0.0, 0.0, 0.0), (fx, fy, 6.0), noise_seed=2).residual
           for fx, fy in ((0.8, 0.0), (-0.8, 0.0), (0.0, 0.8), (0.0, -0.8))]
    f = est.predict(np.stack(res))
    assert f[0, 0] > f[1, 0] + 0.5 and f[2, 1] > f[3, 1] + 0.5, f


def test_same_contact_at_another_resolution_reads_the_same(est):
    big = TactileSensor(SensorSpec.gelsight_mini(), seed=0)
    small = TactileSensor(SensorSpec.gelsight_mini().scaled(120, 160), seed=0)
    a = est.predict(big.press("medium_cylinder", (1.0, 0.0, 0.7), (0.3, -0.2, 6.0), noise_seed=3).residual[None])
    b = est.predict(small.press("medium_cylinder", (1.0, 0.0, 0.7), (0.3, -0.2, 6.0), noise_seed=3).residual[None])
    assert np.abs(a - b).max() < 0.5, (a, b)


def test_unseen_object_is_read_within_a_loose_bound(est, sensor):
    res = [sensor.press(HELDOUT_OBJECTS[0], (0.0, 0.0, 0.0), (0.0, 0.0, fz), noise_seed=4).residual for fz in (2.0, 8.0)]
    fz = est.predict(np.stack(res))[:, 2]
    assert fz[1] > fz[0] + 2.0, fz
