"""benchmarks.verdict (the one runner), verdict_protocols (v1, v2, v3 as values) and verdict_report's statistics:
the exact sign-flip test, the group-sequential looks, the checkpoint rule, bad input, and a unit whose evaluation
raised (never counted)."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2, chi2_contingency, permutation_test

from benchmarks import verdict
from benchmarks import verdict_protocols as vp
from benchmarks import verdict_report as vr

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"


def _outcomes(rate: float, episodes: int = 10) -> list[int]:
    return [1] * round(rate * episodes) + [0] * (episodes - round(rate * episodes))


# --- statistics -------------------------------------------------------------------------------------------------
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
    yates = chi2_contingency([[14, 6], [6, 14]], correction=True)[0]
    assert vr.cmh_p([a], [b]) == pytest.approx(chi2.sf(yates * 39 / 40, 1), rel=1e-9)
    assert vr.cmh_p([np.ones(5)], [np.ones(5)]) == 1.0  # no variance in any stratum


@pytest.mark.parametrize("n", [2, 5, 9, 12])
def test_sign_flip_p_is_scipys_exact_enumeration_ties_included(n):
    rng = np.random.default_rng(n)
    for d in (rng.normal(0.1, 0.2, n), rng.integers(-3, 4, n) / 10):  # the second has ties and zeros
        if abs(d.sum()) < 1e-9:
            continue  # scipy's float sums make a zero mean's p depend on rounding; ours is 1 (below)
        want = permutation_test((d,), np.mean, permutation_type="samples", n_resamples=np.inf).pvalue
        assert vr.sign_flip_p(d) == pytest.approx(want, abs=1e-12)


def test_sign_flip_p_at_24_seeds_counts_every_pattern():
    d = np.random.default_rng(0).normal(0.1, 0.2, 20)  # 2**20 patterns: small enough to enumerate here
    signs = 1 - 2 * ((np.arange(2 ** 20)[:, None] >> np.arange(20)) & 1).astype(np.int8)
    brute = float(np.mean(np.abs(signs @ d) >= abs(d.sum()) - 1e-9))
    assert vr.sign_flip_p(d) == pytest.approx(brute, abs=1e-12)
    assert vr.sign_flip_p(np.ones(24)) == pytest.approx(2 / 2 ** 24)
    assert vr.sign_flip_p([0.1, 0.2, 0.3, 0.1, 0.2]) == pytest.approx(2 / 32)
    assert vr.sign_flip_p([0.2, -0.2]) == 1.0 and vr.sign_flip_p([0, 0, 0]) == 1.0


def test_a_nan_outcome_or_difference_is_refused_never_a_p_of_2_or_a_nan_interval():
    for call in (lambda: vr.sign_flip_p([np.nan] * 5), lambda: vr.sign_flip_p([0.1, np.nan, 0.2]),
                 lambda: vr.paired_t_p([0.1, np.inf]), lambda: vr.sign_flip_p([])):
        with pytest.raises(ValueError, match="^diffs: expected at least"):
            call()
    with pytest.raises(ValueError, match="^outcomes: seed 1 holds NaN or inf"):
        vr.seed_episode_ci([[1, 0, 1], [1, np.nan, 0]])
    with pytest.raises(ValueError, match="at least 2 finite"):  # no t-test at 0 degrees of freedom
        vr.paired_t_p([0.2])
    assert vr.paired_t_p([0.2, 0.2]) == 0.0 and vr.paired_t_p([0.0, 0.0]) == 1.0


def test_holm_step_down():
    assert vr.holm([0.01, 0.04, 0.03, 0.5]) == pytest.approx([0.04, 0.09, 0.09, 0.5])


def test_each_look_stops_for_efficacy_below_its_alpha_for_futility_at_a_non_positive_mean_or_goes_on():
    looks = ((12, 0.001, True), (24, 0.049, False))
    all_up = np.full(24, 0.2)  # p = 2 / 4096 at look 1
    assert vr.sequential_outcome(all_up, looks) == {"p": pytest.approx(2 / 4096), "mean": pytest.approx(0.2),
                                                    "stop": "efficacy", "reject": True, "look": 1}
    down = np.r_[np.full(6, -0.1), np.full(6, 0.05), np.full(12, 0.3)]
    assert vr.sequential_outcome(down, looks)["stop"] == "futility"  # look 2 would have rejected: never reached
    mixed = np.r_[np.tile([0.2, -0.1], 6), np.full(12, 0.15)]
    out = vr.sequential_outcome(mixed, looks)
    assert out["look"] == 2 and out["stop"] == "efficacy" and out["p"] < 0.049
    assert vr.look_decision(mixed, 12, 0.001, True, last=False)["stop"] == "continue"
    noise = np.random.default_rng(1).normal(0, 0.2, 24)
    assert vr.sequential_outcome(noise, looks)["reject"] is False
    with pytest.raises(ValueError, match="needs 24 paired seeds, got 12"):
        vr.sequential_outcome(mixed[:12], looks)


def test_the_design_keeps_its_type_one_error_under_the_bound_and_gains_power_with_the_effect():
    looks = ((12, 0.001, True), (24, 0.049, False))
    null = vr.sequential_power(0.0, 0.2, looks, reps=400)
    assert null["power"] <= 0.05 and null["look_1_futility"] > 0.3  # half the null runs stop at look 1
    small, large = vr.sequential_power(0.08, 0.2, looks, reps=400), vr.sequential_power(0.2, 0.2, looks, reps=400)
    assert small["power"] < large["power"] and large["power"] > 0.95
    assert small["power"] == pytest.approx(small["look_1_efficacy"] + small["look_2_efficacy"])


def test_exact_sign_flip_mde_shrinks_with_seeds_and_with_a_looser_alpha():
    a, b = vr.sign_flip_mde(0.25, 6, 0.05, reps=300), vr.sign_flip_mde(0.25, 10, 0.05, reps=300)
    assert 1.0 > a > b > 0.1 and vr.sign_flip_mde(0.25, 10, 0.05 / 6, reps=300) > b
    assert vr.sign_flip_mde(0.25, 4, 0.05, reps=100) == 1.0  # 2/16 > 0.05: never detectable


def test_seed_level_report_holms_only_the_primary_comparisons_and_counts_seeds_below_reals_worst():
    seeds = range(10)

    def unit(variant, seed, rates):
        return {"variant": variant, "seed": seed, "test": {k: _outcomes(r) for k, r in rates.items()}}

    real = [unit("real", s, {"nominal": 0.5 + 0.02 * s, "low": 0.5}) for s in seeds]
    fa2 = [unit("fa2", s, {"nominal": 0.9, "low": 0.5 + (0.1 if s % 2 else -0.1)}) for s in seeds]
    img = [unit("image_aug", s, {"nominal": 0.3, "low": 0.5}) for s in seeds]
    table, comps = vr.summarise_seed_level(real + fa2 + img, ["real", "fa2", "image_aug"], seeds, ["nominal", "low"],
                                           [("fa2", "nominal"), ("fa2", "low")], 50, reps=200)
    by = {(c["variant"], c["setting"]): c for c in comps}
    helps = by["fa2", "nominal"]
    assert helps["p_sign_flip"] == pytest.approx(2 / 1024) and helps["p_holm"] == pytest.approx(4 / 1024)
    assert helps["verdict"] == "helps" and by["fa2", "low"]["verdict"] == "no detectable effect"
    assert by["image_aug", "nominal"]["p_holm"] is None and by["image_aug", "nominal"]["verdict"] is None
    rows = {(r["variant"], r["setting"]): r for r in table}
    assert rows["image_aug", "nominal"]["below_real_worst"] == 1.0 and rows["fa2", "nominal"]["below_real_worst"] == 0.0
    _, unadjusted = vr.summarise_seed_level(real + fa2, ["real", "fa2"], seeds, ["nominal"], [("fa2", "nominal")], 50,
                                            reps=50, holm_adjust=False)
    assert unadjusted[0]["p_holm"] is None and unadjusted[0]["verdict"] is None  # the caller's design decides


# --- the protocols ----------------------------------------------------------------------------------------------
def test_v3_is_one_primary_question_on_fresh_seeds_and_new_test_episodes_within_alpha():
    v3 = vp.PROTOCOLS["v3"]
    assert v3.primary == (("fa2", "nominal"),) and v3.variants == ("real", "fa2") and v3.correction == "sequential"
    assert not set(v3.train_seeds) & {s for used in vp.USED_TRAIN_SEEDS.values() for s in used}
    assert [look.seeds for look in v3.looks] == [12, 24] and len(v3.train_seeds) == 24
    assert sum(look.alpha for look in v3.looks) <= 0.05  # the union bound
    assert v3.test_episodes == {"nominal": 100, "grip_0.8-1.5": 50, "grip_11-14": 50} and v3.snapshots[-1] == 8000
    start, stop = v3.test_seeds("nominal")
    for name, (a, b) in vp.LOOKED_AT.items():
        assert name.startswith("v3 ") or stop <= a or b <= start
    assert v3.look_seeds(list(v3.train_seeds)) == [list(range(12, 24)), list(range(12, 36))]


def test_v2_as_a_value_is_the_protocol_its_committed_json_ran():
    ran = json.loads((RESULTS / "touch_il_verdict_v2.json").read_text())["protocol"]
    v2 = vp.PROTOCOLS["v2"]
    assert list(v2.train_seeds) == ran["train_seeds"] and list(v2.variants) == ran["variants"]
    assert list(v2.snapshots) == ran["recipe"]["snapshots"] and list(vp.VALIDATION_SEEDS) == ran["validation_seeds"]
    assert {s: list(v2.test_seeds(s)) for s in v2.test_episodes} == dict.fromkeys(ran["settings"], ran["test_seeds"])
    assert {k: list(b) for k, b in v2.settings.items()} == ran["settings"]
    assert len(v2.primary) == ran["power"]["primary_comparisons"] and v2.correction == "holm"
    assert vp.v2_paired_sd() == pytest.approx(0.202, abs=5e-4)


@pytest.mark.parametrize("argv, says", [
    (["--seeds", ",".join(map(str, range(10, 34)))], "--seeds: [10, 11] were trained by v2"),
    (["--seeds", "12,13,14"], "--seeds: 3 seeds; protocol v3 needs 24"),
    (["--seeds", ",".join(map(str, range(100, 125)))], "last look is at 24"),
    (["--seeds", "12,12,13"], "--seeds: expected distinct"),
    (["--test-start", "900010"], "--test-start: test episodes [900010, 900110) overlap the v2 test"),
    (["--test-start", "700000"], "overlap the validation episodes"),
    (["--protocol", "v1"], "--protocol: v1 is retired; its runner is at commit 7c17277"),
    (["--protocol", "v9"], "--protocol: unknown 'v9'"),
    (["--demos", "60"], "--demos: 60 is not within 2..50"),
    (["--jobs", "0"], "--jobs must be >= 1"),
])
def test_bad_input_is_one_line_naming_the_flag(argv, says, capsys):
    with pytest.raises(SystemExit) as exc:
        verdict.parse_args(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0]


def test_an_out_that_is_no_grid_json_is_refused_before_any_unit(tmp_path, capsys):
    (tmp_path / "list.json").write_text("[1]")
    (tmp_path / "notes.json").write_text('{"mine": true}')
    (tmp_path / "old.json").write_text('{"benchmark": "touch_il_verdict_v3"}')
    for out, resume, says in ((tmp_path, True, "is a folder"), (tmp_path / "list.json", True, "not a grid's JSON"),
                              (tmp_path / "notes.json", True, "not a grid's JSON"),
                              (tmp_path / "old.json", False, "exists; pass --resume")):
        with pytest.raises(SystemExit) as exc:
            verdict.parse_args(["--protocol", "v3", "--out", str(out), *(["--resume"] if resume else [])])
        err = capsys.readouterr().err.strip().splitlines()
        assert exc.value.code == 2 and len(err) == 1 and says in err[0], (out, err)
    assert (tmp_path / "list.json").read_text() == "[1]"


def test_v2_runs_by_name_on_its_own_seeds_and_test_range():
    _, args = verdict.parse_args(["--protocol", "v2"])
    assert args.protocol.name == "v2" and args.seeds == list(range(12)) and args.protocol.test_start == 900_000


# --- the rules the grid applies ------------------------------------------------------------------------------------
def test_step_rule_is_per_variant_best_mean_with_fewer_steps_on_ties():
    units = [{"seed": s, "validation": {"1000": _outcomes(0.5), "2000": _outcomes(r2), "3000": _outcomes(0.6)}}
             for s, r2 in enumerate((0.8, 0.4, 0.6))]
    chosen = verdict.choose_step(units, [1000, 2000, 3000])
    assert chosen["step"] == 2000 and chosen["curve"]["2000"]["rates"] == [0.8, 0.4, 0.6]  # 2000 ties 3000


def _results(seeds, rates: dict, step: dict, tested_seeds=None) -> dict:
    """A v3 grid's results: train units (validation best at ``step``, the last snapshot tested) and test units."""
    v3 = vp.PROTOCOLS["v3"]
    units = []
    for s in seeds:
        for v in v3.variants:
            train = {"id": f"train-{v}-s{s}", "kind": "train", "variant": v, "seed": s, "augment_digest": "d"}
            if s in (tested_seeds if tested_seeds is not None else seeds):
                test = {k: _outcomes(rates[v](s), n) for k, n in v3.test_episodes.items()}
                if step[v] == v3.snapshots[-1]:
                    train["test"] = test
                else:
                    units.append({"id": f"test-{v}-s{s}-step{step[v]}", "kind": "test", "variant": v, "seed": s,
                                  "test": test, "augment_digest": "d"})
            units.append(train)
    power = {"statement": "stated first"}
    return {"units": units, "steps": {v: {"step": step[v]} for v in v3.variants},
            "protocol": {"demos": 50, "power": power}}


def test_a_look_is_analysed_only_when_all_its_units_are_tested_then_stops_as_written(tmp_path):
    v3, seeds = vp.PROTOCOLS["v3"], list(range(12, 36))
    rates = {"real": lambda s: 0.6, "fa2": lambda s: 0.8}
    res = _results(seeds[:12], rates, {"real": 6000, "fa2": 8000}, tested_seeds=seeds[:11])
    verdict.report(res, v3, seeds, tmp_path, None, picture=False, reps=50)
    assert res["looks"][0]["complete"] is False and res["looks"][0]["tested_units"] == 22
    assert res["comparisons"] == [] and "p" not in res["looks"][0]  # nothing computed before the look is complete
    res = _results(seeds[:12], rates, {"real": 6000, "fa2": 8000})
    verdict.report(res, v3, seeds, tmp_path, None, picture=False, reps=50)
    look = res["looks"][0]
    assert look["stop"] == "efficacy" and look["verdict"] == "helps" and look["p"] == pytest.approx(2 / 4096)
    assert len(res["looks"]) == 1 and {p["checkpoint_step"] for p in res["policies"]} == {6000, 8000}


def test_look_two_adds_seeds_to_look_ones_statistic_and_decides_at_its_alpha(tmp_path):
    v3, seeds = vp.PROTOCOLS["v3"], list(range(12, 36))
    rates = {"real": lambda s: 0.6, "fa2": lambda s: 0.8 if s % 4 else 0.5}  # +20 three times, -10 once
    res = _results(seeds, rates, {"real": 8000, "fa2": 8000})
    verdict.report(res, v3, seeds, tmp_path, None, picture=False, reps=50)
    first, second = res["looks"]
    assert first["stop"] == "continue" and first["verdict"] is None
    assert second["seeds"] == seeds and second["stop"] == "efficacy" and second["p"] < 0.049
    assert len(res["comparisons"][0]["per_seed_diff"]) == 24 and res["augment_digests"] == ["d"]
    assert res["comparisons"][0]["sentence"].startswith("fa2 vs real, nominal: helps (+12.5 points")


def test_a_final_look_that_does_not_reject_says_no_detectable_effect_in_every_sentence(tmp_path):
    v3, seeds = vp.PROTOCOLS["v3"], list(range(12, 36))
    rates = {"real": lambda s: 0.6, "fa2": lambda s: 0.7 if s % 2 else 0.55}  # +10 and -5 alternately
    res = _results(seeds, rates, {"real": 8000, "fa2": 8000})
    verdict.report(res, v3, seeds, tmp_path, None, picture=False, reps=50)
    second, primary = res["looks"][1], res["comparisons"][0]
    assert second["stop"] == "final" and second["p"] > 0.049 and second["verdict"] == "no detectable effect"
    assert primary["verdict"] == "no detectable effect"
    assert primary["sentence"].startswith("fa2 vs real, nominal: no detectable effect (+2.5 points")


# --- units ---------------------------------------------------------------------------------------------------------
def test_a_unit_whose_episode_raised_is_written_to_failed_and_stops_the_grid_naming_it(tmp_path, monkeypatch):
    import torch
    from act_fixtures import tiny_config

    from controltac_il.app import EvaluationError
    from controltac_il.app.experiment import snapshot_path
    from policies.act import ACT, ACTPolicy, save_checkpoint

    torch.manual_seed(0)
    save_checkpoint(snapshot_path(tmp_path / "policies" / "fa2-s3", 2), ACT(tiny_config()))

    def call(self, observation):
        raise RuntimeError("the policy crashed")

    monkeypatch.setattr(ACTPolicy, "__call__", call)
    unit = {"id": "test-fa2-s3-step2", "kind": "test", "variant": "fa2", "seed": 3, "step": 2}
    ctx = {"runs": str(tmp_path), "test_seeds": {"nominal": (1_000_000, 1_000_002)},
           "settings": {"nominal": (4.0, 7.0)}, "signature": "abc"}
    with pytest.raises(EvaluationError, match=r"^unit test-fa2-s3-step2 \(nominal\): 2 of 2 episodes raised"):
        verdict.run_unit(unit, ctx)
    failed = json.loads((tmp_path / "failed" / "test-fa2-s3-step2.json").read_text())
    assert [e["seed"] for e in failed["errors"]] == [1_000_000, 1_000_001] and "crashed" in failed["errors"][0]["error"]
    assert not (tmp_path / "units").exists()  # nothing counted


@pytest.mark.slow
def test_quick_grid_end_to_end_then_resume_runs_nothing_again(tmp_path):
    out, runs = tmp_path / "v.json", tmp_path / "runs"
    argv = ["--protocol", "v3", "--quick", "--out", str(out), "--runs", str(runs)]
    first = verdict.main(argv)
    assert {u["id"] for u in first["units"] if u["kind"] == "train"} == {"train-real-s12", "train-real-s13",
                                                                         "train-fa2-s12", "train-fa2-s13"}
    assert first["looks"][0]["complete"] and first["force_augment_counts"]["fa2"]["cache_digest"]
    with pytest.raises(SystemExit):  # a grid in --runs needs --resume
        verdict.main(argv)
    again = verdict.main([*argv, "--resume"])
    assert again["units"] == first["units"]  # every unit read back, none rerun
