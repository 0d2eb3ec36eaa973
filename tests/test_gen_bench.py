"""The generator benchmark: its quality metrics on known cases and the --quick run CI relies on."""

import json

import cv2
import numpy as np
import pytest

from benchmarks import generator as bench
from controltac_il.tactile import SensorSpec, TactileSensor


@pytest.fixture(scope="module")
def pair():
    """(reference, target) residuals of one pose at 4 and 7 N, and the background."""
    sensor = TactileSensor(SensorSpec.gelsight_mini().scaled(*bench.RENDER_SIZE))
    ref = sensor.press("big_sphere", (0.3, -0.2, 0.4), (0.0, 0.0, 4.0), noise_seed=1)
    tgt = sensor.press("big_sphere", (0.3, -0.2, 0.4), (0.0, 0.0, 7.0), noise_seed=2)
    return ref.residual[None], tgt.residual[None], sensor.background


def test_quality_of_the_target_itself_is_perfect_and_keeps_all_noise(pair):
    ref, tgt, bg = pair
    q = bench.quality(tgt, tgt, bg, ref)
    assert q["mse"] == 0.0 and q["ssim"] == pytest.approx(1.0)
    assert q["bare_noise_ratio"] == pytest.approx(1.0)
    assert q["n"] == 1


def test_bare_noise_ratio_sees_denoising_and_a_noisier_image(pair):
    ref, tgt, bg = pair
    smooth = np.stack([cv2.GaussianBlur(t, (0, 0), 1.5) for t in tgt])
    assert bench.quality(smooth, tgt, bg, ref)["bare_noise_ratio"] < 0.5
    noisy = np.clip(tgt.astype(np.int16) + np.random.default_rng(0).integers(-6, 7, tgt.shape), 0, 255).astype(np.uint8)
    assert bench.quality(noisy, tgt, bg, ref)["bare_noise_ratio"] > 1.5


def test_eval_pairs_join_images_of_one_pose_with_their_forces(tmp_path):
    refs, tgts, rf, tf, bg = bench.eval_pairs(tmp_path, "unseen", poses=1, forces=3, max_pairs=100)
    n_objects = len(bench.SPLITS["unseen"][0])
    assert len(refs) == n_objects * 3 * 2  # every ordered pair of the 3 forces of each pose
    assert refs.shape == tgts.shape == (len(refs), *bench.RENDER_SIZE, 3) and refs.dtype == np.uint8
    assert rf.shape == tf.shape == (len(refs), 3) and not np.any(np.all(rf == tf, axis=1))
    assert bg.shape == (len(refs), *bench.RENDER_SIZE, 3)  # each pair's own sensor background
    again = bench.eval_pairs(tmp_path, "unseen", poses=1, forces=3, max_pairs=5)  # the cached data, a seeded subset
    assert len(again[0]) == 5 and np.array_equal(again[0], bench.eval_pairs(tmp_path, "unseen", 1, 3, 5)[0])


@pytest.mark.slow  # the whole --quick benchmark (~30 s): its metrics and pairs are tested above, the run itself with -m slow
def test_quick_run_writes_the_table_json_targets_and_sheet(tmp_path, capsys):
    out = tmp_path / "gen.json"
    doc = bench.main(["--quick", "--pairs", "6", "--threads", "1", "--out", str(out), "--cache", str(tmp_path / "data")])
    assert json.loads(out.read_text()) == json.loads(json.dumps(doc))
    names = [m["method"] for m in doc["methods"]]
    assert names[:5] == ["reference copy", "physics re-render", "target through the model size", "default DDIM-1",
                         "default DDIM-2"]
    assert any(n.startswith("fast DDIM-") for n in names)
    by = {m["method"]: m for m in doc["methods"]}
    t = doc["targets"]
    copy, default = by["reference copy"], by["default DDIM-1"]
    for split in ("seen", "unseen", "seen_240", "unseen_240"):
        assert copy[split]["n"] == 6 and copy[split]["bare_noise_ratio"] == pytest.approx(1.0, abs=0.15)
        assert default[split]["mse"] < copy[split]["mse"]  # the shipped model beats copying the reference
        # the read-back of the true frames does not depend on the method; a copy reads the reference's force
        assert copy[split]["true_readback_fz_mae"] == pytest.approx(default[split]["true_readback_fz_mae"])
        assert default[split]["readback_fz_mae"] < copy[split]["readback_fz_mae"]
    assert t["unseen_240_readback_ratio_to_true"] == pytest.approx(default["unseen_240"]["readback_fz_mae"]
                                                           / default["unseen_240"]["true_readback_fz_mae"])
    bound = by["target through the model size"]  # the true target resized to the model and back: only fine detail lost
    assert bound["unseen_240"]["mse"] < 0.2 * copy["unseen_240"]["mse"] and "img_per_s_b32" not in bound
    assert t["unseen_240_bound_through_model_size"] == pytest.approx(bound["unseen_240"]["mse"] / copy["unseen_240"]["mse"])
    speed = doc["autoencoder_speed"]
    assert speed["f8_at_240x320"]["config"]["image_size"] == [240, 320] and speed["shipped"]["img_per_s"] > 0 and speed["batch"] == 4
    assert copy["unseen_sensor"]["n"] == 6 and default["img_per_s_b32_240"] > 0
    assert doc["settings"]["splits"]["unseen_sensor"]["sensors"] == "unseen"
    assert default["img_per_s_b1"] > 0 and default["peak_rss_mb"] > default["batch_growth_mb"] > 0
    assert t["default_setting"] == "default DDIM-1"
    assert t["unseen_mse_ratio_to_copy"] == pytest.approx(default["unseen"]["mse"] / copy["unseen"]["mse"])
    assert "unseen MSE" in capsys.readouterr().out
    sheet = cv2.imread(str(out.with_suffix(".png")))
    assert sheet.shape == (24 + 9 * 2 * bench.RENDER_SIZE[0], 4 * 2 * bench.RENDER_SIZE[1], 3)
    split = doc["forceaugment_split"]  # the presets on ForceAugment's pairs, nominal sensor, both sizes
    assert [(r["size"], r["sensor"]) for r in split["rows"]] == [("240", "nominal"), ("120", "nominal")]
    assert set(split["rows"][0]["presets"]) == {"fast", "default"} and split["rows"][0]["pairs"] == 6
    assert (tmp_path / "generator_fa.png").stat().st_size > 0


def test_speed_rounds_time_every_checkpoint_and_keep_each_rounds_figure(tmp_path, monkeypatch):
    """benchmarks.generator_speed: one row per (checkpoint, dtype, frames, steps, batch), the median over rounds with
    the rounds; img/s counts the frames timed (--quick: batches of 4), here against an injected timer of 0.5 s per
    call; "auto" resolves to whole chunks, at most the frames there are (--quick: 8)."""
    from benchmarks import generator_speed

    monkeypatch.setattr(generator_speed, "median_time", lambda fn, repeats, warmup: fn() or 0.5)
    doc = generator_speed.main(["--quick", "--rounds", "2", "--repeats", "1", "--threads", "1", "--checkpoints",
                                "fast", "--batch-sizes", "32", "auto", "--steps", "1", "--pairs", "0", "--out",
                                str(tmp_path / "s.json")])
    rows = json.loads((tmp_path / "s.json").read_text())["rows"]
    assert rows == doc["rows"] and len(rows) == len(generator_speed.SIZES) * 2
    for r in rows:
        assert r["checkpoint"] == "fast" and r["dtype"] == "float32" and len(r["img_per_s_rounds"]) == 2
        frames = 4 if r["batch"] == 4 else 8
        assert r["batch_rows"] == frames and r["img_per_s_rounds"] == [frames / 0.5] * 2 == [r["img_per_s"]] * 2
        assert r["dit_parameters"] > 0 and r["mse_ratio_to_copy"] is None


def test_the_frontier_joins_errors_to_timings_by_checkpoint_and_steps():
    """Each point: the generator row's error ÷ the copy's, the speed rows' rounds at 240×320; untimed rows left out."""
    from benchmarks.generator_frontier import frontier_points

    copy = {"kind": "copy", "unseen_240": {"mse": 40.0}}
    methods = [copy, {"kind": "quality", "steps": 1, "parameters": 9, "unseen_240": {"mse": 10.0}},
               {"kind": "quality", "steps": 5, "parameters": 9, "unseen_240": {"mse": 12.0}}]
    speed = [{"checkpoint": "quality", "frames": "240", "steps": 1, "img_per_s_rounds": [30.0, 32.0]},
             {"checkpoint": "quality", "frames": "120", "steps": 5, "img_per_s_rounds": [11.0]}]
    assert frontier_points(methods, speed) == {"quality": [([30.0, 32.0], 0.25, 1)]}


def test_the_forceaugment_split_breaks_the_ratio_down_by_sign_size_and_object():
    """Ratios of the means (not means of ratios) per cell; an empty cell is None."""
    from benchmarks.generator_fa import breakdown

    pred, copy = np.array([1.0, 2.0, 3.0, 4.0]), np.array([2.0, 2.0, 6.0, 8.0])
    out = breakdown(pred, copy, np.array([-1.0, 1.5, 3.0, 6.0]), np.array(["a", "b", "a", "b"]))
    assert out["all"] == {"ratio": 10 / 18, "pairs": 4} and out["increase"] == {"ratio": 9 / 16, "pairs": 3}
    assert out["decrease"] == {"ratio": 0.5, "pairs": 1}
    assert [out[k]["ratio"] for k in ("|dFz| 0-2 N", "|dFz| 2-5 N", "|dFz| 5-inf N")] == [0.75, 0.5, 0.5]
    assert out["objects"] == {"a": {"ratio": 0.5, "pairs": 2}, "b": {"ratio": 0.6, "pairs": 2}}
    assert breakdown(pred[:1], copy[:1], np.array([-1.0]), np.array(["a"]))["increase"] is None


def test_the_forceaugment_pairs_ask_what_forceaugment_asks():
    """Each pair's target is ForceAugment's plan for its episode and copy (the paper's offsets and jitter), clamped by
    the generator's range decision; references at the demos' grip."""
    from benchmarks.generator_fa import GRIP_FZ, fa_pairs
    from controltac_il.augment.config import ForceAugmentConfig
    from controltac_il.augment.draws import plan_frame
    from controltac_il.generator import ForceGenerator
    from controltac_il.generator.forces import VALIDATED_RANGE
    from controltac_il.tactile import SensorSpec, TactileSensor

    pairs = fa_pairs(TactileSensor(SensorSpec.gelsight_mini().scaled(60, 80)), ForceGenerator.from_pretrained(), 4)
    assert pairs["ref"].shape == pairs["tgt"].shape == pairs["noise"].shape == (4, 60, 80, 3)
    assert ((pairs["ref_f"][:, 2] >= GRIP_FZ[0]) & (pairs["ref_f"][:, 2] <= GRIP_FZ[1])).all()
    for k in range(4):
        asked = plan_frame(ForceAugmentConfig(), k, 1 + k % 2, 0, 0, pairs["ref_f"][k]).target[2]
        assert pairs["tgt_f"][k, 2] == np.clip(asked, *VALIDATED_RANGE.fz)
    assert not np.array_equal(pairs["tgt"], pairs["noise"])  # another noise draw of the same target


def test_the_committed_forceaugment_picture_is_drawn_from_the_committed_json(tmp_path):
    """``--plot-from`` redraws generator_fa.png from a results JSON, measuring nothing: the committed picture is the
    one the committed generator.json gives, pixel for pixel."""
    import shutil

    from benchmarks.figure_text import RESULTS
    from benchmarks.generator_fa import main

    shutil.copy(RESULTS / "generator.json", tmp_path / "generator.json")
    main(["--plot-from", str(tmp_path / "generator.json")])
    drawn, committed = (cv2.imread(str(p / "generator_fa.png")) for p in (tmp_path, RESULTS))
    assert drawn is not None and drawn.shape == committed.shape and (drawn == committed).all()
    shutil.copy(RESULTS / "env.json", tmp_path / "env.json")  # a results JSON without the split
    with pytest.raises(SystemExit) as refused:
        main(["--plot-from", str(tmp_path / "env.json")])
    assert refused.value.code == 2
