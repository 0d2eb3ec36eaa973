"""Estimator training: learning on a synthetic task, exact resume after a crash, data helpers."""

import math

import numpy as np
import pytest
import torch

from controltac_il.estimators import EstimatorConfig, EstimatorTrainConfig, fit
from controltac_il.estimators.data import (
    estimate_noise_std,
    no_contact_residuals,
    native_no_contact,
    pixel_noise_std,
    split_by_pose,
)

from files import tree_bytes

TINY = EstimatorConfig(input_height=32, input_width=40, widths=(8, 8, 16, 16), hidden=32)


def blobs(n: int, seed: int, h: int = 48, w: int = 60):
    """Residuals whose red blob grows with Fz and shifts with (Fx, Fy): a learnable toy task."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:h, :w]
    f = np.stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), rng.uniform(0.5, 10, n)], 1).astype(np.float32)
    out = np.full((n, h, w, 3), 127.0, np.float32)
    for i in range(n):
        cx, cy = rng.uniform(18, w - 18), rng.uniform(14, h - 14)
        r2 = (xx - cx - 4 * f[i, 0]) ** 2 + (yy - cy + 4 * f[i, 1]) ** 2
        out[i, ..., 0] += 10 * f[i, 2] * np.exp(-r2 / (2 * (2 + 0.4 * f[i, 2]) ** 2))
        out[i, ..., 2] -= 40 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / 8)
    out += rng.normal(0, 1.5, out.shape)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8), f


def test_fit_learns_and_sets_force_normalisation():
    x, f = blobs(240, 0)
    xv, fv = blobs(60, 1)
    est, hist = fit(x, f, TINY, EstimatorTrainConfig(steps=150, batch_size=32, lr=3e-3, warmup=10, eval_every=0),
                    val=(xv, fv), progress=False)
    np.testing.assert_allclose(est.config.force_mean, f.mean(0), rtol=1e-5, atol=1e-6)
    baseline = np.abs(fv - f.mean(0)).mean()  # predicting the training mean
    assert hist[-1]["step"] == 150
    assert hist[-1]["val_mae_mean"] < 0.6 * baseline


class Crash(Exception):
    pass


def test_resume_after_crash_gives_identical_weights(tmp_path):
    x, f = blobs(64, 2)
    train = EstimatorTrainConfig(steps=12, batch_size=8, warmup=2, checkpoint_every=5, eval_every=0)
    ref, _ = fit(x, f, TINY, train, progress=False)

    def crash(est, step, history):
        if step == 10:
            raise Crash

    with pytest.raises(Crash):
        fit(x, f, TINY, train, state_dir=tmp_path / "st", progress=False, on_checkpoint=crash)
    resumed, _ = fit(x, f, TINY, train, state_dir=tmp_path / "st", resume=True, progress=False)
    for (k, a), b in zip(ref.model.state_dict().items(), resumed.model.state_dict().values()):
        np.testing.assert_array_equal(a.numpy(), b.numpy(), err_msg=k)


def test_resume_needs_state_and_matching_config(tmp_path):
    x, f = blobs(16, 3)
    train = EstimatorTrainConfig(steps=2, batch_size=4, warmup=1, eval_every=0)
    with pytest.raises(FileNotFoundError, match="no training state"):
        fit(x, f, TINY, train, state_dir=tmp_path / "st", resume=True, progress=False)
    fit(x, f, TINY, train, state_dir=tmp_path / "st", progress=False)
    other = EstimatorConfig(**{**TINY.to_dict(), "hidden": 16})
    with pytest.raises(ValueError, match="another model config"):
        fit(x, f, other, train, state_dir=tmp_path / "st", resume=True, progress=False)


def test_fit_rejects_bad_labels():
    x, f = blobs(8, 4)
    with pytest.raises(ValueError, match=r"forces must have shape \(N, 3\)"):
        fit(x, f[:, :2], TINY, EstimatorTrainConfig(steps=1), progress=False)
    xv, fv = x[:4], f[:4].copy()
    with pytest.raises(ValueError, match=r"val forces must have shape \(N, 3\) matching residuals \(N=3\)"):
        fit(x, f, TINY, EstimatorTrainConfig(steps=1), val=(xv[:3], fv), progress=False)
    fv[1, 0] = np.nan  # a NaN validation label would make every val MAE NaN, silently
    with pytest.raises(ValueError, match="val forces contain NaN"):
        fit(x, f, TINY, EstimatorTrainConfig(steps=1), val=(xv, fv), progress=False)
    f[0, 2] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        fit(x, f, TINY, EstimatorTrainConfig(steps=1), progress=False)


def test_train_config_validation_and_schedule():
    with pytest.raises(ValueError, match="steps"):
        EstimatorTrainConfig(steps=0)
    with pytest.raises(ValueError, match="min_lr"):
        EstimatorTrainConfig(lr=1e-3, min_lr=1e-2)
    with pytest.raises(ValueError, match="lr"):
        EstimatorTrainConfig(lr=float("inf"))
    t = EstimatorTrainConfig(steps=100, lr=1e-3, min_lr=1e-5, warmup=10)
    opt = torch.optim.AdamW(torch.nn.Linear(2, 2).parameters(), lr=t.lr)
    sched, lrs = t.schedule(opt), []
    for _ in range(t.steps):
        lrs.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    # the schedule by hand: warm-up (s + 1) / warmup, then cosine to min_lr
    by_hand = [t.lr * (s + 1) / t.warmup if s < t.warmup else
           t.min_lr + 0.5 * (t.lr - t.min_lr) * (1 + math.cos(math.pi * (s - t.warmup) / (t.steps - t.warmup)))
           for s in range(t.steps)]
    np.testing.assert_allclose(lrs, by_hand, rtol=1e-12)
    assert lrs[0] == pytest.approx(1e-4) and lrs[9] == pytest.approx(1e-3)
    assert lrs[99] == pytest.approx(1e-5, rel=0.05)


def test_no_contact_frames_and_noise_estimates():
    empty = no_contact_residuals(50, 40, 50, noise_std=2.0, seed=0)
    assert empty.dtype == np.uint8 and empty.shape == (50, 40, 50, 3)
    assert estimate_noise_std(empty) == pytest.approx(2.0, rel=0.1)
    assert pixel_noise_std(empty) == pytest.approx(2.0, rel=0.1)
    x, _ = blobs(30, 5)  # noise 1.5 plus contact blobs: the neighbour-difference estimate ignores the blobs
    assert pixel_noise_std(x) == pytest.approx(1.5, rel=0.15)
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="noise_std"):
            no_contact_residuals(2, 8, 8, noise_std=bad)


def test_native_no_contact_matches_the_bare_sensor(tmp_path):
    from controltac_il.tactile import SensorSpec
    from controltac_il.tactile.dataset import load_dataset, write_dataset

    spec = SensorSpec.gelsight_mini().scaled(60, 80)
    ds = load_dataset(write_dataset(tmp_path / "d", objects=("big_sphere",), poses_per_object=1, forces_per_pose=2,
                                    seed=0, spec=spec, progress=False))
    empty = native_no_contact(ds, 4, size=(30, 40), seed=1)
    assert empty.shape == (4, 30, 40, 3) and empty.dtype == np.uint8
    # the bare sensor's noise (spec.noise_std at 60x80), averaged down 2x2 by the resize
    assert np.std(empty.astype(np.float32) - 127) == pytest.approx(spec.noise_std / 2, rel=0.25)
    assert not np.array_equal(empty[0], empty[1])
    assert native_no_contact(ds, 0, size=(30, 40)).shape == (0, 30, 40, 3)


def test_split_by_pose_keeps_poses_whole_and_covers_every_object():
    groups = {(obj, p): [100 * i + 10 * p + k for k in range(3)]
              for i, obj in enumerate(["a", "b"]) for p in range(10)}
    kept, held = split_by_pose(groups, 0.2, seed=0)
    assert sorted(kept + held) == sorted(i for v in groups.values() for i in v)
    for key, rows in groups.items():
        assert set(rows) <= set(kept) or set(rows) <= set(held), key
    held_poses = {k for k, rows in groups.items() if rows[0] in held}
    assert {k[0] for k in held_poses} == {"a", "b"} and len(held_poses) == 4
    assert split_by_pose(groups, 0.2, seed=0) == (kept, held)
    assert split_by_pose(groups, 0.0) == (sorted(kept + held), [])


def test_train_cli_writes_checkpoint_and_resumes(tmp_path, capsys):
    import json

    from controltac_il.estimators import ForceEstimator
    from controltac_il.estimators.train import main
    from controltac_il.tactile import SensorSpec
    from controltac_il.tactile.dataset import write_dataset

    data = write_dataset(tmp_path / "data", objects=("big_sphere", "cross"), poses_per_object=3, forces_per_pose=3,
                         seed=0, spec=SensorSpec.gelsight_mini().scaled(60, 80), progress=False)
    out = tmp_path / "est"
    common = ["--data", str(data), "--out", str(out), "--input-size", "32", "40", "--batch-size", "4",
              "--checkpoint-every", "2", "--val-fraction", "0.3"]
    assert main(common + ["--steps", "4"]) == 0
    assert "validation MAE" in capsys.readouterr().out
    state = json.loads((tmp_path / "est.train_state" / "state.json").read_text())
    assert state["step"] == 4 and state["history"][-1]["step"] == 4
    assert main(common + ["--steps", "6", "--resume"]) == 0
    state = json.loads((tmp_path / "est.train_state" / "state.json").read_text())
    assert state["step"] == 6
    est = ForceEstimator.from_pretrained(out)
    assert (est.config.input_height, est.config.input_width) == (32, 40)
    assert "Validation" in (out / "README.md").read_text()
    assert main(["--data", str(tmp_path / "nothing"), "--out", str(tmp_path / "x")]) == 2
    assert "manifest.csv" in capsys.readouterr().err


# -- never destroy what the user owns, never compute on garbage, one-line errors --------------------

@pytest.fixture(scope="module")
def presses(tmp_path_factory):
    from controltac_il.tactile import SensorSpec
    from controltac_il.tactile.dataset import write_dataset

    return write_dataset(tmp_path_factory.mktemp("est") / "data", objects=("big_sphere", "cross"), poses_per_object=3,
                         forces_per_pose=2, seed=0, spec=SensorSpec.gelsight_mini().scaled(60, 80), progress=False)


def _cli(presses, out, *extra):
    from controltac_il.estimators.train import main

    return main(["--data", str(presses), "--out", str(out), "--input-size", "32", "40", "--batch-size", "4",
                 "--val-fraction", "0.3", "--steps", "2", *extra])


@pytest.mark.parametrize("flags, named", [
    (["--steps", "-1"], "--steps"), (["--batch-size", "0"], "--batch-size"), (["--lr", "inf"], "--lr"),
    (["--val-fraction", "1.5"], "--val-fraction"), (["--no-contact-fraction", "1"], "--no-contact-fraction"),
    (["--input-size", "4", "4"], "--input-size"), (["--checkpoint-every", "-2"], "--checkpoint-every"),
])
def test_train_cli_validation_errors_are_one_line_naming_the_flag(presses, tmp_path, capsys, flags, named):
    assert _cli(presses, tmp_path / "e", *flags) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and named in err[0], err
    assert not (tmp_path / "e").exists()


def test_train_cli_missing_data_is_one_line(tmp_path, capsys):
    from controltac_il.estimators.train import main

    assert main(["--data", str(tmp_path / "nowhere"), "--out", str(tmp_path / "e")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nowhere" in err[0] and "--data" in err[0]


def test_train_cli_never_replaces_a_folder_of_the_users(presses, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    before = tree_bytes(tmp_path)
    for extra in ([], ["--overwrite"], ["--resume"]):
        assert _cli(presses, out, *extra) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(out) in err[0], (extra, err)
        assert tree_bytes(tmp_path) == before


def test_train_cli_a_previous_run_needs_resume_or_overwrite(presses, tmp_path, capsys):
    out = tmp_path / "est"
    assert _cli(presses, out) == 0
    before = tree_bytes(tmp_path)
    capsys.readouterr()
    assert _cli(presses, out) == 2
    err = capsys.readouterr().err
    assert "--resume" in err and "--overwrite" in err and tree_bytes(tmp_path) == before
    assert _cli(presses, out, "--overwrite", "--seed", "1") == 0
    assert tree_bytes(tmp_path) != before


def test_nonfinite_loss_stops_the_fit_keeping_the_last_good_state(tmp_path, monkeypatch):
    import json

    from controltac_il.training import NonFiniteLoss
    import importlib
    fit_module = importlib.import_module("controltac_il.estimators.fit")

    x, f = blobs(32, 0)
    calls = []

    def loss(pred, target):
        calls.append(1)
        value = torch.nn.functional.l1_loss(pred, target)
        return value * float("nan") if len(calls) == 4 else value

    monkeypatch.setattr(fit_module, "_loss", loss)
    with pytest.raises(NonFiniteLoss, match=r"step 4.*holds step 2"):
        fit(x, f, TINY, EstimatorTrainConfig(steps=10, batch_size=8, checkpoint_every=2, eval_every=0), state_dir=tmp_path / "s",
            progress=False)
    assert json.loads((tmp_path / "s" / "state.json").read_text())["step"] == 2


def test_ctrl_c_saves_the_current_step(tmp_path, monkeypatch):
    import json
    import os
    import signal

    from controltac_il.training import TrainingInterrupted
    import importlib
    fit_module = importlib.import_module("controltac_il.estimators.fit")

    x, f = blobs(32, 0)
    calls, written = [], []

    def loss(pred, target):
        calls.append(1)
        if len(calls) == 3:
            os.kill(os.getpid(), signal.SIGINT)
        return torch.nn.functional.l1_loss(pred, target)

    monkeypatch.setattr(fit_module, "_loss", loss)
    with pytest.raises(TrainingInterrupted, match="step 3"):
        fit(x, f, TINY, EstimatorTrainConfig(steps=50, batch_size=8, checkpoint_every=20, eval_every=0), state_dir=tmp_path / "s",
            progress=False, on_checkpoint=lambda est, step, hist: written.append(step))
    assert json.loads((tmp_path / "s" / "state.json").read_text())["step"] == 3 and written == [3]
