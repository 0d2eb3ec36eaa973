"""benchmarks.touch_il: bad input, statistics, and the --quick grid end to end (resumable)."""

import json

import pytest
from scipy.stats import fisher_exact

from benchmarks import touch_il as bench


@pytest.mark.parametrize("argv, flag", [
    (["--variants", "real,fa3"], "--variants: unknown ['fa3']"),
    (["--demos", "20,60"], "--demos: budget 60 is larger than the 50 collected demos"),
    (["--demos", "20,35", "--collect", "30"], "--demos: budget 35 is larger than the 30 collected"),
    (["--demos", "1"], "--demos: every budget must be >= 2"),
    (["--demos", "a,b"], "--demos: expected a comma list"),
    (["--shifted-low", "3", "3"], "--shifted-low: empty grip band"),
    (["--shifted-high", "9", "20"], "--shifted-high: 9-20 N is outside the finger servo's range"),
    (["--shifted-low", "2", "5"], "--shifted-low: (2.0, 5.0) must lie below the nominal band"),
    (["--nominal-grip", "7", "4"], "--nominal-grip: empty grip band"),
    (["--steps", "0"], "--steps must be >= 1"),
])
def test_bad_input_is_one_line_naming_the_flag(argv, flag, capsys):
    with pytest.raises(SystemExit) as exc:
        bench.parse_args(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flag in err[0], err


def test_cameras_cannot_see_the_offset_but_touch_can():
    """Same hand pose, peg held at -8, -5, +5, +8 mm: byte-identical camera images; the contact moves."""
    from controltac_il.app.touch_probes import vision_check

    check = vision_check(seeds=(0, 3))
    assert check["max_pixel_diff"] == {"third_view": 0, "wrist": 0}
    # the left pad's image x runs along -hand x: +3 / +10 / +3 mm move the contact ~24 / 79 / 24 px left
    cols = check["tactile_column_px_mean"]
    assert cols[0] > cols[1] > cols[2] > cols[3]
    assert check["tactile_column_px_min_step"] > 15
    assert 60 < cols[1] - cols[2] < 100


def test_p_values_are_one_sided_fisher_against_real_in_the_same_budget_and_setting():
    def cell(variant, demos, setting, k, n=50):
        return {"variant": variant, "demos": demos, "setting": setting, "successes": k, "episodes": n}

    cells = [cell("real", 50, "nominal", 20), cell("fa1", 50, "nominal", 30), cell("vision_only", 50, "nominal", 2),
             cell("fa1", 50, "shifted_low", 40), cell("real", 20, "nominal", 45), cell("fa2", 20, "nominal", 40)]
    bench.add_p_values(cells)
    p = {(c["variant"], c["demos"], c["setting"]): c["p_vs_real"] for c in cells}
    assert p[("real", 50, "nominal")] is None
    assert p[("fa1", 50, "nominal")] == pytest.approx(
        fisher_exact([[30, 20], [20, 30]], alternative="greater").pvalue)
    assert p[("vision_only", 50, "nominal")] == pytest.approx(  # that real beats vision_only
        fisher_exact([[20, 30], [2, 48]], alternative="greater").pvalue)
    assert p[("vision_only", 50, "nominal")] < 1e-4
    assert p[("fa1", 50, "shifted_low")] is None  # no real cell to compare with
    assert p[("fa2", 20, "nominal")] > 0.9  # worse than real: no evidence of a gain


@pytest.mark.slow  # the history grid's end-to-end run (~30 s); the v2 verdict's units and statistics are tested in the default suite
def test_quick_grid_writes_cells_picture_and_resumes_without_retraining(tmp_path, monkeypatch):
    monkeypatch.setenv("CONTROLTAC_CACHE", str(tmp_path / "cache"))
    out, runs = tmp_path / "touch.json", tmp_path / "runs"
    res = bench.main(["--quick", "--out", str(out), "--runs", str(runs)])
    doc = json.loads(out.read_text())
    assert doc["machine"]["cores"] and doc["benchmark"] == "touch_il"
    cells = doc["cells"]
    assert len(cells) == 4 * 3  # vision_only, real, fa1, image_aug x three settings
    for c in cells:
        assert {"variant", "demos", "copies", "setting", "grip_n", "successes", "episodes", "wilson95"} <= set(c)
        assert c["episodes"] == 1 and 0 <= c["successes"] <= 1 and c["demos"] == 3
        assert c["wilson95"][0] <= c["successes"] / c["episodes"] <= c["wilson95"][1]
    grips = {c["setting"]: c["grip_n"] for c in cells}
    assert grips == {"nominal": [4.0, 7.0], "shifted_low": [1.5, 3.0], "shifted_high": [8.0, 10.0]}
    assert {c["variant"]: c["copies"] for c in cells} == {"vision_only": 0, "real": 0, "fa1": 1, "image_aug": 1}
    assert {c["variant"]: c["augment"]["kind"] for c in cells if c["augment"]} == {"fa1": "force", "image_aug": "image"}
    assert out.with_suffix(".png").read_bytes()[:4] == b"\x89PNG"
    assert doc["vision_check"]["max_pixel_diff"] == {"third_view": 0, "wrist": 0}
    bands = doc["grip_response"]["bands"]
    assert bands["shifted_low"]["true_intensity"] < bands["nominal"]["true_intensity"] < bands["shifted_high"]["true_intensity"]
    assert bands["nominal"]["copy_mse"] == 0.0 and bands["shifted_low"]["copy_mse"] > 0
    assert len(list((runs / "cells").glob("*.json"))) == 12
    # vision_only was trained without tactile streams
    vo = json.loads((runs / "policies" / "vision_only-n3" / "best" / "config.json").read_text())
    assert vo["act"]["tactile_names"] == []
    real = json.loads((runs / "policies" / "real-n3" / "best" / "config.json").read_text())
    assert real["act"]["tactile_names"] == ["left", "right"]
    with pytest.raises(SystemExit):  # an existing grid is not silently continued or mixed
        bench.main(["--quick", "--out", str(out), "--runs", str(runs)])
    # an interrupted grid: one cell lost; --resume evaluates only that one and retrains nothing
    (runs / "cells" / "real-n3-shifted_high.json").unlink()
    stamps = {p: p.stat().st_mtime_ns for p in (runs / "policies").rglob("*.safetensors")}
    again = bench.main(["--quick", "--out", str(out), "--runs", str(runs), "--resume"])
    assert {p: p.stat().st_mtime_ns for p in (runs / "policies").rglob("*.safetensors")} == stamps
    strip = lambda cs: sorted((c["variant"], c["setting"], c["successes"]) for c in cs)  # noqa: E731
    assert strip(again["cells"]) == strip(res["cells"])
    assert len(json.loads(out.read_text())["wall_s"]["earlier_invocations"]) == 1


def test_force_augment_stage_records_only_settings_that_differ_from_the_paper():
    from controltac_il.augment import ForceAugmentStage

    paper = ForceAugmentStage(2)
    assert "offset_range" not in paper.description and "out_of_range" not in paper.description
    assert ForceAugmentStage(2, offset_range=(-3.0, 10.0)).description == paper.description  # the default, named
    sym = ForceAugmentStage(2, offset_range=(-5, 5), out_of_range="skip")
    assert sym.description["offset_range"] == [-5.0, 5.0] and sym.description["out_of_range"] == "skip"
    with pytest.raises(ValueError, match="offset_range"):
        ForceAugmentStage(2, offset_range=(5, -5))


def test_bad_offset_range_names_the_flag(capsys):
    with pytest.raises(SystemExit):
        bench.parse_args(["--offset-range", "5", "-5"])
    assert "--offset-range: low 5 N is above high -5 N" in capsys.readouterr().err


def test_a_cell_whose_episode_raised_stops_the_grid_naming_it_and_writes_nothing(tmp_path, monkeypatch):
    """An episode that raises is never a failed episode: the unit stops with one line naming the cell."""
    import torch
    from act_fixtures import tiny_config

    from controltac_il.app import EvaluationError
    from policies.act import ACT, ACTPolicy, save_checkpoint

    torch.manual_seed(0)
    run = tmp_path / "policies" / "real-n3"
    for sub in ("last", "best"):  # trained to the asked steps already: run_unit goes straight to evaluation
        save_checkpoint(run / sub, ACT(tiny_config()), meta={"step": 5, "best_val_l1": 1.0})

    def call(self, observation):
        raise RuntimeError("the policy crashed")

    monkeypatch.setattr(ACTPolicy, "__call__", call)
    with pytest.raises(EvaluationError, match=r"^cell real-n3-nominal: 2 of 2 episodes raised and were not counted"):
        bench.run_unit("real", 3, demos_dir=str(tmp_path), runs=str(tmp_path), steps=5, batch_size=2, copies=0,
                       generator=None, max_force_copies=0, bands={"nominal": (4.0, 7.0)}, eval_episodes=2,
                       signature="x", todo_settings=["nominal"], eval_seed=900_000)
    assert not (tmp_path / "cells").exists()
