"""Force estimator: input validation, resizing, checkpoint round trip, config validation."""

import json

import numpy as np
import pytest
import torch

from controltac_il.estimators import EstimatorConfig, ForceEstimator, validate_residuals
from controltac_il.estimators.estimator import preprocess


@pytest.fixture()
def est():
    torch.manual_seed(0)
    return ForceEstimator(EstimatorConfig(force_mean=(0.1, -0.2, 5.0), force_std=(0.5, 0.5, 3.0)))


def test_predict_shape_dtype_and_any_resolution(est):
    rng = np.random.default_rng(0)
    for h, w in [(64, 80), (128, 160), (240, 320)]:
        out = est.predict(rng.integers(110, 145, (3, h, w, 3), dtype=np.uint8))
        assert out.shape == (3, 3) and out.dtype == np.float32 and np.isfinite(out).all()


def test_float_input_in_range_matches_uint8(est):
    r = np.random.default_rng(1).integers(110, 145, (2, 128, 160, 3), dtype=np.uint8)
    np.testing.assert_allclose(est.predict(r), est.predict(r.astype(np.float32)), atol=1e-5)


def test_batching_does_not_change_predictions(est):
    r = np.random.default_rng(2).integers(110, 145, (7, 64, 80, 3), dtype=np.uint8)
    np.testing.assert_allclose(est.predict(r, batch_size=2), est.predict(r, batch_size=64), atol=1e-5)


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((128, 160, 3), np.uint8), r"\(N, H, W, 3\)"),
        (np.zeros((2, 3, 128, 160), np.uint8), r"\(N, H, W, 3\)"),
        (np.zeros((0, 128, 160, 3), np.uint8), "at least one image"),
        (np.zeros((1, 4, 4, 3), np.uint8), "8x8"),
        (np.zeros((1, 64, 80, 3), np.int64), "dtype int64"),
        (np.zeros((1, 64, 80, 3), bool), "dtype bool"),
        (np.full((1, 64, 80, 3), np.nan, np.float32), "NaN"),
        (np.full((1, 64, 80, 3), 300.0, np.float32), r"\[0, 255\]"),
        (np.full((1, 64, 80, 3), 127 / 255, np.float32), r"values lie in \[0, 1\]; residual pixels are 0-255"),
        ([[1, 2, 3]], "numpy array"),
    ],
)
def test_bad_input_is_rejected_with_clear_error(est, bad, match):
    with pytest.raises(ValueError, match=match):
        est.predict(bad)


def test_raw_sensor_frames_are_warned_about_and_residuals_are_not(est):
    """A raw frame without contact reads 17-20 N: the warning names the fix; the frame's residual passes quietly."""
    import warnings

    from controltac_il.tactile import SensorSpec, TactileSensor
    from controltac_il.tactile.residual import to_residual

    sensor = TactileSensor(SensorSpec.gelsight_mini().scaled(120, 160), seed=0)
    raw = np.stack([sensor.press("big_sphere", (0, 0, 0), (0, 0, fz)).image for fz in (2.0, 6.0)])
    with pytest.warns(UserWarning, match=r"2 of 2 frames sampled look like raw sensor frames.*to_residual"):
        est.predict(raw)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est.predict(to_residual(raw, sensor.background))


def test_validate_accepts_torch_tensor():
    t = torch.full((1, 16, 16, 3), 127, dtype=torch.uint8)
    assert isinstance(validate_residuals(t), np.ndarray)


def test_a_bfloat16_tensor_reads_as_the_same_float_pixels_and_is_range_checked(est):
    """NumPy has no bfloat16: such a tensor (0-255 integers are exact in it) reads as float pixels, its forces those
    of the same uint8 frames; out of range it is refused like any float array, never a TypeError from NumPy."""
    r = np.random.default_rng(3).integers(110, 145, (2, 64, 80, 3), dtype=np.uint8)
    np.testing.assert_allclose(est.predict(torch.from_numpy(r).to(torch.bfloat16)), est.predict(r), atol=1e-5)
    with pytest.raises(ValueError, match=r"\[0, 255\]"):
        est.predict(torch.full((1, 64, 80, 3), 300.0, dtype=torch.bfloat16))


def test_preprocess_maps_offset_to_zero_and_resizes():
    cfg = EstimatorConfig(input_height=32, input_width=40)
    x = preprocess(np.full((2, 240, 320, 3), 127, np.uint8), cfg)
    assert x.shape == (2, 3, 32, 40)
    assert x.abs().max() < 1e-5
    x = preprocess(np.full((1, 32, 40, 3), 127 + 32, np.uint8), cfg)
    assert torch.allclose(x, torch.ones_like(x))


def test_save_load_round_trip_is_exact(est, tmp_path):
    r = np.random.default_rng(3).integers(110, 145, (4, 128, 160, 3), dtype=np.uint8)
    est.save(tmp_path / "ck", card="# card\n")
    assert sorted(p.name for p in (tmp_path / "ck").iterdir()) == ["README.md", "config.json", "model.safetensors",
                                                                    "model_card.json"]
    loaded = ForceEstimator.from_pretrained(tmp_path / "ck")
    assert loaded.config == est.config
    np.testing.assert_array_equal(loaded.predict(r), est.predict(r))
    assert len(loaded.checkpoint_hash) == 16
    # saving again over an existing folder replaces it whole (atomic folder swap)
    est.save(tmp_path / "ck")
    assert not (tmp_path / "ck" / "README.md").exists()


def test_from_pretrained_missing_folder_is_clear(tmp_path):
    with pytest.raises(FileNotFoundError, match="model.safetensors"):
        ForceEstimator.from_pretrained(tmp_path)


def test_checkpoint_is_verified_against_its_card(est, tmp_path):
    from controltac_il.checkpoint import CheckpointError
    from controltac_il.estimators.estimator import DEFAULT_CHECKPOINT

    import hashlib

    weights = hashlib.sha256((DEFAULT_CHECKPOINT / "model.safetensors").read_bytes()).hexdigest()[:16]
    assert ForceEstimator.from_pretrained().checkpoint_hash == weights  # the weights' own hash, not the card's text
    assert EstimatorConfig().residual_offset == 127.0
    est.save(tmp_path / "ck")
    weights = tmp_path / "ck" / "model.safetensors"
    weights.write_bytes(weights.read_bytes()[:-4] + b"\x00\x00\x80\x7f")  # last float -> inf: another hash
    with pytest.raises(CheckpointError, match="model.safetensors is corrupted"):
        ForceEstimator.from_pretrained(tmp_path / "ck")
    assert (DEFAULT_CHECKPOINT / "model_card.json").is_file()


def test_config_rejects_unknown_and_bad_fields(tmp_path):
    with pytest.raises(ValueError, match=r"^colour: Unexpected keyword argument"):
        EstimatorConfig.from_dict({"input_height": 64, "colour": 1})
    with pytest.raises(ValueError, match="force_std"):
        EstimatorConfig(force_std=(1.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="input_width"):
        EstimatorConfig(input_width=4)
    with pytest.raises(ValueError, match="widths"):
        EstimatorConfig(widths=(8, 0))
    cfg = EstimatorConfig(widths=[8, 8, 16, 16])
    assert EstimatorConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg


def test_contact_gate_zeroes_frames_without_visible_contact(est):
    flat = np.full((1, 120, 160, 3), 127, np.uint8)
    noisy = np.clip(np.rint(np.random.default_rng(4).normal(127, 1.5, (1, 120, 160, 3))), 0, 255).astype(np.uint8)
    touch = flat.copy()
    touch[0, 50:58, 70:80] = [150, 120, 110]  # 80 px = 0.4 % of the frame, 23 grey levels
    out = est.predict(np.concatenate([flat, noisy, touch]))
    assert (out[:2] == 0).all()
    raw = est.predict(np.concatenate([flat, noisy, touch]), gate=False)
    np.testing.assert_array_equal(out[2], raw[2])
    assert est.contact_visible(np.concatenate([flat, noisy, touch])).tolist() == [False, False, True]
    ungated = ForceEstimator(EstimatorConfig(contact_threshold=None), model=est.model)
    assert ungated.contact_visible(flat).tolist() == [True]
    with pytest.raises(ValueError, match="contact_threshold"):
        EstimatorConfig(contact_threshold=0.0)
    with pytest.raises(ValueError, match="min_contact_fraction"):
        EstimatorConfig(min_contact_fraction=1.5)


def test_nonfinite_weights_and_config_values_are_refused_in_one_line_naming_the_file(est, tmp_path):
    from safetensors.torch import load_file, save_file

    from controltac_il.checkpoint import CheckpointError, sign

    est.save(tmp_path / "ck")
    weights = tmp_path / "ck" / "model.safetensors"
    tensors = load_file(str(weights))
    next(v for v in tensors.values() if v.is_floating_point()).view(-1)[0] = float("nan")
    save_file(tensors, str(weights))
    sign(tmp_path / "ck")  # the hash matches: the NaN itself is refused
    with pytest.raises(CheckpointError, match="model.safetensors: tensors .* NaN or inf"):
        ForceEstimator.from_pretrained(tmp_path / "ck")
    est.save(tmp_path / "ck2")
    cfg = json.loads((tmp_path / "ck2" / "config.json").read_text())
    for field, value in (("force_std", [1.0, float("inf"), 1.0]), ("residual_scale", 0.0),
                         ("force_mean", [float("nan"), 0.0, 0.0])):
        (tmp_path / "ck2" / "config.json").write_text(json.dumps({**cfg, field: value}))
        with pytest.raises(CheckpointError) as info:
            ForceEstimator.from_pretrained(tmp_path / "ck2")
        assert "\n" not in str(info.value) and field in str(info.value) and "config.json" in str(info.value)


def test_a_reading_that_is_not_finite_is_a_fault_never_passed_on(est, monkeypatch):
    """A broken checkpoint's NaN reading would reach ForceAugment as a reference force: it stops instead."""
    from controltac_il.cli import RunFault

    forward = est.model.forward

    def nan_for_frame_1(x):
        y = forward(x).clone()
        y[1, 2] = float("nan")
        return y

    monkeypatch.setattr(est.model, "forward", nan_for_frame_1)
    touch = np.full((3, 120, 160, 3), 127, np.uint8)
    touch[:, 50:58, 70:80] = [150, 120, 110]
    with pytest.raises(RunFault, match=r"^the force estimator's output holds NaN or inf values for 1 of 3 frames "
                                       r"\(e.g. index 1\)"):
        est.predict(touch)


def test_saving_never_replaces_a_file_or_folder_of_the_users(est, tmp_path):
    """A checkpoint is written only where nothing is, into an empty folder, or over a checkpoint whose every file
    it rewrites; anything else is refused before a byte is written, and left as it was."""
    mine = tmp_path / "mywork"
    mine.mkdir()
    (mine / "thesis.tex").write_text("x")
    (tmp_path / "notes.txt").write_text("n")
    for path, says in ((mine, "is not a checkpoint folder"), (tmp_path / "notes.txt", "is not a folder")):
        with pytest.raises(ValueError, match=f"^{path}: exists and {says}"):
            est.save(path)
    assert (mine / "thesis.tex").read_text() == "x" and (tmp_path / "notes.txt").read_text() == "n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mywork", "notes.txt"]  # no temporary left either
    (tmp_path / "empty").mkdir()
    ckpt = est.save(tmp_path / "empty")
    before = {p.name: p.read_bytes() for p in ckpt.iterdir()}
    est.save(ckpt)  # a checkpoint over itself: replaced
    assert {p.name: p.read_bytes() for p in ckpt.iterdir()} == before
    (ckpt / "my_notes.md").write_text("mine")
    with pytest.raises(ValueError, match=r"holds \['my_notes.md'\], which this checkpoint does not write"):
        est.save(ckpt)
    assert (ckpt / "my_notes.md").read_text() == "mine"


@pytest.mark.parametrize("call, says", [
    (lambda est, x: est.predict(x, batch_size=0), "^batch_size must be an int >= 1, got 0$"),
    (lambda est, x: est.predict(x, batch_size=2.5), "^batch_size must be an int >= 1, got 2.5$"),
    (lambda est, x: ForceEstimator(est.config, device="gpu"), "^device: expected a torch device such as cpu"),
    # a CUDA device this machine lacks (every one, without CUDA): torch's AssertionError is a traceback
    (lambda est, x: ForceEstimator(est.config, device=f"cuda:{torch.cuda.device_count()}"),
     r"^device: 'cuda:\d+', but this machine has \d+ CUDA device\(s\); use cpu$"),
])
def test_a_bad_batch_size_or_device_is_named(est, call, says):
    with pytest.raises(ValueError, match=says):
        call(est, np.full((2, 32, 40, 3), 127, np.uint8))
