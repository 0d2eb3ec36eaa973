"""benchmarks.touch_il_verdict: the protocol's choice rules, its statistics and its bad input."""

import numpy as np
import pytest
from scipy.stats import chi2, chi2_contingency

from benchmarks import touch_il_verdict as verdict
from benchmarks import verdict_report as vr


def test_two_level_interval_of_constant_outcomes_is_a_point_and_covers_the_mean_otherwise():
    assert vr.seed_episode_ci([np.ones(10), np.ones(7)]) == (1.0, (1.0, 1.0))
    outcomes = [np.r_[np.ones(8), np.zeros(2)], np.r_[np.ones(3), np.zeros(7)], np.r_[np.ones(5), np.zeros(5)]]
    mean, (lo, hi) = vr.seed_episode_ci(outcomes)
    assert mean == pytest.approx(0.5333, abs=1e-4)
    assert lo < mean < hi and hi - lo > 0.2  # seed-to-seed spread (0.3 .. 0.8) widens it well past one binomial


def test_paired_difference_is_the_mean_of_per_seed_differences_and_refuses_unpaired_input():
    a = [np.array([1, 1, 1, 0]), np.array([1, 0, 0, 0])]
    b = [np.array([0, 0, 1, 0]), np.array([1, 0, 0, 0])]
    diff, (lo, hi), per_seed = vr.paired_diff(a, b)
    assert per_seed == [0.5, 0.0] and diff == 0.25 and lo <= 0.25 <= hi
    with pytest.raises(ValueError, match="same seeds"):
        vr.paired_diff(a, b[:1])


def test_cmh_on_one_stratum_is_yates_chi_square_scaled_by_n_minus_1_over_n():
    a, b = np.r_[np.ones(14), np.zeros(6)], np.r_[np.ones(6), np.zeros(14)]
    table = [[14, 6], [6, 14]]
    yates = chi2_contingency(table, correction=True)[0]
    assert vr.cmh_p([a], [b]) == pytest.approx(chi2.sf(yates * 39 / 40, 1), rel=1e-9)
    assert vr.cmh_p([np.ones(5)], [np.ones(5)]) == 1.0  # no variance in any stratum


def test_sign_flip_floor_and_holm_step_down():
    assert vr.sign_flip_p([0.1, 0.2, 0.3, 0.1, 0.2]) == pytest.approx(2 / 32)
    assert vr.sign_flip_p([0, 0, 0]) == 1.0
    assert vr.holm([0.01, 0.04, 0.03, 0.5]) == pytest.approx([0.04, 0.09, 0.09, 0.5])


def test_verdict_needs_both_the_holm_p_and_the_interval():
    assert vr.verdict(0.2, (0.05, 0.35), 0.01) == "helps"
    assert vr.verdict(-0.2, (-0.35, -0.05), 0.01) == "hurts"
    assert vr.verdict(0.2, (-0.01, 0.35), 0.01) == "no detectable effect"  # seeds' interval crosses 0
    assert vr.verdict(0.2, (0.05, 0.35), 0.2) == "no detectable effect"


def _tune(rates_by_step: dict[int, list[float]], episodes: int = 10) -> dict:
    out = {}
    for seed in range(5):
        val = {str(s): [1] * round(r[seed] * episodes) + [0] * (episodes - round(r[seed] * episodes))
               for s, r in rates_by_step.items()}
        out[("real", seed)] = {"validation": val}
    return out


def test_steps_rule_takes_the_first_snapshot_reaching_the_target_else_the_best_mean_with_fewer_steps_on_ties():
    tune = _tune({1000: [0.9, 0.9, 0.3, 0.9, 0.5], 2000: [0.9, 0.8, 0.8, 0.9, 0.3], 3000: [1.0] * 5})
    assert verdict.choose_steps(tune, range(5), [1000, 2000, 3000])["step"] == 2000
    tune = _tune({1000: [0.5] * 5, 2000: [0.7, 0.7, 0.7, 0.3, 0.3], 3000: [0.7, 0.7, 0.7, 0.3, 0.3]})
    chosen = verdict.choose_steps(tune, range(5), [1000, 2000, 3000])
    assert chosen["step"] == 2000 and not chosen["target_reached"]


def test_shift_rule_picks_the_largest_drop_on_each_side_when_it_costs_ten_points():
    bands = {"low": (1.5, 3.0), "very_low": (0.8, 1.5), "high": (8.0, 10.0)}

    def unit(rates):
        return {name: [1] * round(10 * r) + [0] * (10 - round(10 * r)) for name, r in rates.items()}

    shift = {s: {"validation": unit({"low": 0.7, "very_low": 0.5, "high": 0.85})} for s in range(5)}
    out = verdict.choose_shifts(shift, [0.9] * 5, bands, (4.0, 7.0))
    assert out["chosen"] == ["very_low"] and out["finding"] is None  # high costs 5 points only
    assert out["validation_drops"]["very_low"]["drop"] == pytest.approx(0.4)
    shift = {s: {"validation": unit({"low": 0.85, "very_low": 0.9, "high": 0.9})} for s in range(5)}
    out = verdict.choose_shifts(shift, [0.9] * 5, bands, (4.0, 7.0))
    assert out["chosen"] == ["low"] and "no candidate shift" in out["finding"]


@pytest.mark.parametrize("argv, flag", [
    (["--variants", "real,fa3"], "--variants: unknown ['fa3']"),
    (["--variants", "fa2,fa4"], "--variants: real is required"),
    (["--seeds", "0,1,2"], "--seeds: the protocol needs >= 5"),
    (["--seeds", "0,1,1,2,3"], "--seeds: expected distinct"),
    (["--test-seeds", "700010", "700060"], "--test-seeds: [700010, 700060) overlaps the --validation-seeds"),
    (["--validation-seeds", "10", "40"], "--validation-seeds: [10, 40) overlaps the demos seeds [0, 50)"),
    (["--demos", "60"], "--demos: 60 is not within 2..50"),
    (["--shift-candidates", "0.2-1"], "--shift-candidates: 0.2-1 N is empty or outside the finger servo's range"),
    (["--shift-candidates", "3-x"], "--shift-candidates: expected LOW-HIGH"),
    (["--snapshots", "1000,1500"], "--snapshots: every step must be a positive multiple"),
    (["--jobs", "0"], "--jobs must be >= 1"),
])
def test_bad_input_is_one_line_naming_the_flag(argv, flag, capsys):
    with pytest.raises(SystemExit) as exc:
        verdict.parse_args(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert flag in err and "Traceback" not in err


def test_the_protocol_fixes_disjoint_seed_ranges_and_every_variant_on_the_same_seeds():
    _, args = verdict.parse_args([])
    proto = verdict.protocol_of(args)
    ranges = [proto["demo_seeds"], proto["validation_seeds"], proto["test_seeds"]]
    assert all(a[1] <= b[0] for a, b in zip(ranges, ranges[1:]))
    assert proto["variants"] == ["vision_only", "real", "fa2", "fa4", "image_aug"]
    assert len(proto["train_seeds"]) >= 5 and proto["test_seeds"][1] - proto["test_seeds"][0] >= 50
    assert verdict.signature_of(proto) == verdict.signature_of(verdict.protocol_of(args))


@pytest.mark.slow
def test_quick_grid_end_to_end_then_resume_runs_nothing_again(tmp_path):
    out, runs = tmp_path / "v.json", tmp_path / "runs"
    argv = ["--quick", "--variants", "real,fa2", "--shift-candidates", "1.5-3", "--out", str(out), "--runs", str(runs)]
    first = verdict.main(argv)
    assert {u["id"] for u in first["units"]} == {"tune-real-s0", "tune-real-s1", "shift-real-s0-step2",
                                                "shift-real-s1-step2", "policy-real-s0", "policy-real-s1",
                                                "policy-fa2-s0", "policy-fa2-s1"}
    assert [c["variant"] for c in first["comparisons"]] == ["fa2", "fa2"]
    assert first["force_augment_counts"]["fa2"]["tactile_frames"] > 0 and out.with_suffix(".png").is_file()
    with pytest.raises(SystemExit):  # a grid in --runs needs --resume
        verdict.main(argv)
    again = verdict.main([*argv, "--resume"])
    assert again["units"] == first["units"]  # every unit read back, none rerun
