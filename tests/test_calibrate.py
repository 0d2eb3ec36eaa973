"""``python -m controltac_il.calibrate`` on presses the sensor model writes: a bundle whose estimator and generator
load by the bundle's name (ForceEstimator, ForceGenerator, ForceAugment, the augment CLI), fine-tuned from their
bases; resume; one-line errors. Tiny bases (a generator trained here for 3 + 3 steps, a small estimator) keep it fast."""

import json
import re
import shutil

import numpy as np
import pytest
import torch

from controltac_il.calibrate import main
from controltac_il.calibrate.bundle import subset_presses
from controltac_il.estimators import EstimatorConfig, ForceEstimator
from controltac_il.generator import ForceGenerator
from controltac_il.generator.training.cli import main as train_generator
from controltac_il.tactile import TRAIN_OBJECTS, SensorSpec
from controltac_il.tactile.dataset import load_dataset, write_dataset

TINY = ["--ae-steps", "3", "--dit-steps", "3", "--ae-batch", "2", "--dit-batch", "4", "--ae-crop", "32", "40",
        "--checkpoint-every", "2", "--warmup-steps", "1", "--no-contact-frames", "2", "--threads", "1",
        "--image-size", "64", "80"]


@pytest.fixture(scope="module")
def bases(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("calibrate")
    presses = write_dataset(tmp / "presses", TRAIN_OBJECTS[:2], poses_per_object=5, forces_per_pose=3, seed=3,
                            spec=SensorSpec.gelsight_mini().scaled(60, 80), progress=False)
    assert train_generator(["stage1", "--data", str(presses), "--out", str(tmp / "gen"), *TINY]) == 0
    torch.manual_seed(0)
    est = ForceEstimator(EstimatorConfig(input_height=16, input_width=16, widths=(4, 4), hidden=8,
                                         force_mean=(0.0, 0.0, 4.0), force_std=(0.3, 0.3, 2.0)))
    est.save(tmp / "est")
    return tmp, presses


def test_bundle_loads_by_name_everywhere_and_moved_from_its_bases(bases, tmp_path, capsys):
    tmp, presses = bases
    out = tmp_path / "my_sensor"
    args = ["--presses", str(presses), "--out", str(out), "--base-generator", str(tmp / "gen" / "final"),
            "--base-estimator", str(tmp / "est"), "--estimator-steps", "6", "--ae-steps", "2", "--dit-steps", "2",
            "--batch", "4", "--threads", "1"]
    assert main(args) == 0
    said = capsys.readouterr().out
    record = json.loads((out / "calibration.json").read_text())
    assert record["images"] == 30 and record["estimator"]["held_out"]["frames"] == 30
    held = record["estimator"]["held_out"]  # every one of the 10 grasps held out once
    assert [r["frames"] for r in held["per_grasp"]] == [3] * 10 and held["grasps"] == 10
    decision = held["decision"]
    assert "wrote" in said and [line for line in said.splitlines() if line.startswith("estimator")] == [decision["why"]]
    assert decision["why"].startswith("estimator declined") and len(decision["interval"]) == 2
    assert record["generator"]["held_out_rows"] and (out / "report.png").stat().st_size > 0
    assert not (out.parent / "my_sensor.partial").exists()
    est, base = ForceEstimator.from_pretrained(out), ForceEstimator.from_pretrained(tmp / "est")
    assert est.checkpoint_hash == record["estimator"]["hash"] != base.checkpoint_hash
    assert est.config.force_mean == base.config.force_mean and est.config.input_mix is not None  # base net, new colours
    gen = ForceGenerator.from_pretrained(out)
    assert gen.checkpoint_hash == record["generator"]["hash"] != record["generator"]["base_hash"]
    x = np.full((1, 60, 80, 3), 127, np.uint8)
    assert gen.generate(x, np.zeros((1, 3), np.float32)).shape == x.shape
    readme = (out / "README.md").read_text()
    assert "estimator Fz MAE" in readme and decision["why"] in readme and "| held-out grasp | frames |" in readme
    assert main(args) == 2 and "exists" in capsys.readouterr().err  # never written over
    from lerobot_like import GEL, LeRobotLike, episodes

    from controltac_il.augment import ForceAugment
    from controltac_il.augment.cli import load_models, parser

    # the tiny random base cannot beat the constant: the bundle says so and ForceAugment takes the nominal reference
    assert record["estimator"]["use_estimator"] is False
    with pytest.warns(UserWarning, match="does not beat the constant baseline"):
        aug = ForceAugment(LeRobotLike(episodes(labels=False)), generator=str(out), tactile_keys=[GEL], copies=1,
                           mode="online", progress=False)
    assert (aug.generator.checkpoint_hash, aug.estimator.checkpoint_hash) == (gen.checkpoint_hash, "nominal")
    cli = parser().parse_args(["--dataset", str(tmp_path), "--out", str(tmp_path / "c"), "--generator", str(out)])
    with pytest.warns(UserWarning, match="does not beat the constant baseline"):
        g, e = load_models(cli, pose=False)
    assert (g.checkpoint_hash, e.checkpoint_hash) == (gen.checkpoint_hash, "nominal")
    cli = parser().parse_args(["--dataset", str(tmp_path), "--out", str(tmp_path / "c"), "--estimator", str(out)])
    with pytest.warns(UserWarning, match="does not beat the constant baseline"):  # the bundle named as --estimator
        assert load_models(cli, pose=False)[1].checkpoint_hash == "nominal"
    from controltac_il.augment import ForceAugmentStage

    stage = ForceAugmentStage(1, generator=str(out), steps=1, mode="online", tactile_keys=[GEL])
    with pytest.warns(UserWarning, match="does not beat the constant baseline"):  # train_act.py --generator BUNDLE
        augmented = stage(LeRobotLike(episodes(labels=False)))
    assert augmented.dataset.estimator.checkpoint_hash == "nominal"


def test_bad_presses_and_stopped_runs_are_one_line(bases, tmp_path, capsys):
    tmp, presses = bases
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.png").write_bytes(b"x")
    cases = [(["--presses", str(tmp_path / "photos"), "--out", str(tmp_path / "o")], "--presses: not a presses folder"),
             (["--presses", str(tmp_path / "none"), "--out", str(tmp_path / "o")], "--presses: "),
             (["--presses", str(presses), "--out", str(tmp_path / "o"), "--dit-steps", "0"], "--dit-steps: "),
             (["--presses", str(presses), "--out", str(tmp_path / "o"), "--val-fraction", "1"], "--val-fraction: "),
             (["--presses", str(presses), "--out", str(tmp_path / "o"), "--device", "abacus"], "--device: "),
             (["--recordings", str(tmp_path), "--out", str(tmp_path / "o"), "--size", "0", "-5"],
              "--size: expected H W in pixels, each in [8, 2048], got 0 -5"),  # else OpenCV's resize traceback
             (["--presses", str(presses), "--out", str(tmp_path / "o"), "--lag", "auto"],
              "--lag: reads recordings, used only with --recordings")]
    (tmp_path / "s.partial").mkdir()
    cases.append((["--presses", str(presses), "--out", str(tmp_path / "s")], "--resume"))
    ds = load_dataset(presses)
    one = subset_presses(ds, next(iter(ds.pose_groups().values())), tmp_path / "one_pose")
    cases.append((["--presses", str(one), "--out", str(tmp_path / "o")],
                  f"--presses: {one} holds 1 grasp (contact poses); at least 3 are needed"))
    two = subset_presses(ds, [r for g in list(ds.pose_groups().values())[:2] for r in g], tmp_path / "two_poses")
    cases.append((["--presses", str(two), "--out", str(tmp_path / "o")],
                  f"--presses: {two} holds 2 grasps (contact poses); at least 3 are needed"))
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "config.json").write_text("{")
    for flag in ("--base-estimator", "--base-generator", "--lr", "--threads"):
        value = {"--lr": "nan", "--threads": "0"}.get(flag, str(tmp_path / "broken"))
        cases.append((["--presses", str(presses), "--out", str(tmp_path / "b"), flag, value], f"{flag}: "))
    for argv, expected in cases:
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and expected in err, (argv, err)
    assert not (tmp_path / "b.partial").exists() and not (tmp_path / "b").exists()  # refused before any write


def test_a_subset_copy_stopped_midway_leaves_only_whole_entries_and_a_rerun_completes(bases, tmp_path, monkeypatch):
    _, presses = bases
    ds = load_dataset(presses)
    rows = [r for g in list(ds.pose_groups().values())[:3] for r in g]
    copyfile, calls = shutil.copyfile, []

    def killed_on_the_fifth(src, dst, **kw):  # a kill while a folder is half copied
        calls.append(src)
        if len(calls) == 5:
            raise KeyboardInterrupt
        return copyfile(src, dst, **kw)

    def listing(root):
        return sorted(str(f.relative_to(root)) for f in root.rglob("*")) if root.is_dir() else [root.name]

    monkeypatch.setattr(shutil, "copyfile", killed_on_the_fifth)
    with pytest.raises(KeyboardInterrupt):
        subset_presses(ds, rows, tmp_path / "sub")
    monkeypatch.undo()
    entries = ("background.png", "backgrounds", "images", "meta.json")
    kept = [n for n in entries if (tmp_path / "sub" / n).exists()]
    assert len(kept) < sum((presses / n).exists() for n in entries)  # the kill left something out...
    assert all(listing(tmp_path / "sub" / n) == listing(presses / n) for n in kept)  # ...and nothing half there
    sub = subset_presses(ds, rows, tmp_path / "sub")
    assert all(listing(sub / n) == listing(presses / n) for n in entries if (presses / n).exists())
    assert len(load_dataset(sub)) == len(rows)


def test_held_out_poses_never_split_a_pose_and_need_two():
    from controltac_il.calibrate.bundle import held_out_poses

    groups = {("cross", 0): [0, 1, 2], ("sphere", 0): [3, 4], ("slim", 0): [5]}  # one pose per object
    train, val = held_out_poses(groups, 0.1)
    assert sorted(train + val) == list(range(6)) and val and train
    assert all(set(g) <= set(val) or set(g) <= set(train) for g in groups.values())
    with pytest.raises(ValueError, match="one contact pose only"):
        held_out_poses({("cross", 0): [0, 1]}, 0.1)


def test_held_out_poses_hold_out_the_asked_share_when_objects_have_few_poses():
    """100 presses of 6 objects are 2 poses each: one per object would hold out half; 0.2 of 12 poses is 2."""
    from controltac_il.calibrate.bundle import held_out_poses

    few = {(obj, p): [8 * (2 * o + p) + k for k in range(8)] for o, obj in enumerate("abcdef") for p in range(2)}
    train, val = held_out_poses(few, 0.2)
    assert (len(train), len(val)) == (80, 16) and sorted(train + val) == list(range(96))
    many = {(obj, p): [10 * o + p] for o, obj in enumerate("abcdef") for p in range(10)}  # 10 poses each: per object
    train, val = held_out_poses(many, 0.2)
    assert len(val) == 12 and sorted({r // 10 for r in val}) == list(range(6))
    assert held_out_poses(many, 0.2) == (train, val)  # fixed seed


def test_leaving_one_grasp_out_needs_three_grasps_before_fitting_anything():
    from controltac_il.calibrate.bundle import cross_validated

    residuals, fz = np.zeros((4, 8, 8, 3), np.uint8), np.array([1.0, 2.0, 3.0, 4.0])
    with pytest.raises(ValueError, match=r"^the labelled frames hold 2 contact poses; at least 3 are needed"):
        cross_validated(None, residuals, fz, np.array([0, 0, 1, 1]), steps=1)  # never reaches the base estimator


def test_a_bundle_from_recordings_names_its_final_folder(bases, tmp_path):
    """Recordings are written as presses inside OUT.partial first; the finished bundle names OUT/presses."""
    import cv2

    tmp, presses = bases
    ds = load_dataset(presses)
    recordings = tmp_path / "recordings"
    for g, rows in enumerate(list(ds.pose_groups().values())[:3]):
        rows = sorted(rows, key=lambda i: ds.forces()[i, 2])
        frames = [ds.background_of(rows[0])] + [ds.image(i) for i in rows]
        (recordings / f"grasp{g}").mkdir(parents=True)
        for k, img in enumerate(frames):
            cv2.imwrite(str(recordings / f"grasp{g}" / f"{k:03d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        fz = [0.0] + [float(ds.forces()[i, 2]) for i in rows]
        (recordings / f"grasp{g}.csv").write_text("fz\n" + "\n".join(map(str, fz)) + "\n")
    out = tmp_path / "my_sensor"
    assert main(["--recordings", str(recordings), "--out", str(out), "--size", "60", "80", "--base-generator",
                 str(tmp / "gen" / "final"), "--base-estimator", str(tmp / "est"), "--estimator-steps", "2",
                 "--ae-steps", "1", "--dit-steps", "1", "--batch", "4", "--threads", "1"]) == 0
    readme = (out / "README.md").read_text()
    assert f"in `{(out / 'presses').resolve()}`" in readme and ".partial" not in readme
    assert json.loads((out / "calibration.json").read_text())["presses"] == str((out / "presses").resolve())


def test_a_stopped_calibration_resumes_to_the_same_estimator(bases, tmp_path, capsys, monkeypatch):
    import controltac_il.calibrate.bundle as bundle

    tmp, presses = bases
    out = tmp_path / "lab"
    args = ["--presses", str(presses), "--out", str(out), "--base-estimator", str(tmp / "est"), "--estimator-steps",
            "6", "--ae-steps", "1", "--dit-steps", "1", "--batch", "4", "--threads", "1", "--estimator-method", "finetune"]

    def stopped(*_):  # Ctrl-C once the generator's fine-tune starts: the estimator part is done
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(bundle, "generator_part", stopped)
        assert main([*args, "--base-generator", str(tmp / "gen" / "final")]) == 130
    staging = tmp_path / "lab.partial"
    first = ForceEstimator.from_pretrained(staging / "estimator").checkpoint_hash
    assert "interrupted" in capsys.readouterr().err and not out.exists()
    assert main([*args, "--base-generator", str(tmp / "gen" / "final")]) == 2  # a stopped run needs --resume
    assert main([*args, "--base-generator", str(tmp / "gen" / "final"), "--resume"]) == 0
    assert ForceEstimator.from_pretrained(out).checkpoint_hash == first and not staging.exists()
    record = json.loads((out / "calibration.json").read_text())["estimator"]
    assert record["method"] == "the whole base network fine-tuned" and record["steps"] == 6
    assert sum(v is not None for v in record["held_out"]["predicted_fz"]) == record["held_out"]["frames"] < 30


@pytest.mark.slow  # 6 s on the 2-core machine, most of it the 9.9 M DiT's fine-tune and loads: with -m slow
def test_calibration_starts_from_the_quality_preset(bases, tmp_path):
    """``--base-generator quality``: the bundle's generator is the 9.9 M-parameter DiT fine-tuned, its base
    recorded by hash (2 + 2 steps at batch 4: the plumbing, not the curve of benchmarks.finetune)."""
    tmp, presses = bases
    out = tmp_path / "from_quality"
    assert main(["--presses", str(presses), "--out", str(out), "--base-generator", "quality", "--base-estimator",
                 str(tmp / "est"), "--estimator-steps", "2", "--ae-steps", "2", "--dit-steps", "2", "--batch", "4",
                 "--threads", "1"]) == 0
    record = json.loads((out / "calibration.json").read_text())
    base, gen = ForceGenerator.from_pretrained("quality"), ForceGenerator.from_pretrained(out)
    assert record["generator"]["base_hash"] == base.checkpoint_hash != gen.checkpoint_hash == record["generator"]["hash"]
    assert gen.config.dit == base.config.dit and gen.config.dit.hidden_size == 256
    x = np.full((2, 60, 80, 3), 127, np.uint8)
    assert gen.generate(x, np.zeros((2, 3), np.float32)).shape == x.shape


@pytest.mark.parametrize("text", ["{}", "[1, 2]", "{\"estimator\": 3}", "not json"])
def test_a_bundle_whose_record_holds_no_decision_is_refused_naming_it(tmp_path, text):
    """A calibration.json no calibrate wrote: one line naming the file, never a KeyError from deep inside."""
    from controltac_il.augment.reference import bundle_estimator
    from controltac_il.estimators.estimator import BUNDLE_PART

    (tmp_path / BUNDLE_PART).mkdir()
    (tmp_path / "calibration.json").write_text(text)
    with pytest.raises(ValueError, match=f"^{re.escape(str(tmp_path / 'calibration.json'))}: not a calibration record"):
        bundle_estimator(tmp_path)
