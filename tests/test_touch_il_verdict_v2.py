"""benchmarks.touch_il_verdict_v2: the protocol's rules, seed-level statistics, bad input, and a unit whose
evaluation raised (never counted)."""

import json

import numpy as np
import pytest
import torch
from act_fixtures import tiny_config

from benchmarks import touch_il_verdict_v2 as v2
from benchmarks import verdict_report as vr
from policies.act import ACT, ACTPolicy, save_checkpoint


def _unit(variant, seed, rates: dict, episodes=10, kind="test"):
    outcomes = {k: [1] * round(r * episodes) + [0] * (episodes - round(r * episodes)) for k, r in rates.items()}
    return {"variant": variant, "seed": seed, "kind": kind, **({"test": outcomes} if kind == "test" else
                                                                {"validation": outcomes})}


def test_step_rule_is_per_variant_best_mean_with_fewer_steps_on_ties():
    units = [_unit("fa2", s, {"1000": 0.5, "2000": r2, "3000": 0.6}, kind="train")
             for s, r2 in enumerate((0.8, 0.4, 0.6))]
    assert v2.choose_step(units, [1000, 2000, 3000])["step"] == 2000  # means 0.5, 0.6, 0.6: the earlier wins
    assert v2.choose_step(units, [1000, 2000, 3000])["curve"]["2000"]["rates"] == [0.8, 0.4, 0.6]


def test_exact_sign_flip_mde_shrinks_with_seeds_and_with_a_looser_alpha():
    assert vr._exact_sign_flip_p(np.ones((1, 5)))[0] == pytest.approx(2 / 32)
    assert vr.sign_flip_p(np.ones(10)) == pytest.approx(vr._exact_sign_flip_p(np.ones((1, 10)))[0])
    a, b = vr.sign_flip_mde(0.25, 6, 0.05, reps=400), vr.sign_flip_mde(0.25, 10, 0.05, reps=400)
    assert 1.0 > a > b > 0.1 and vr.sign_flip_mde(0.25, 10, 0.05 / 6, reps=400) > b
    assert vr.sign_flip_mde(0.25, 4, 0.05, reps=100) == 1.0  # 2/16 > 0.05: never detectable


def test_seed_level_report_holms_only_the_primary_comparisons_and_counts_seeds_below_reals_worst():
    seeds = range(10)
    real = [_unit("real", s, {"nominal": 0.5 + 0.02 * s, "low": 0.5}) for s in seeds]
    fa2 = [_unit("fa2", s, {"nominal": 0.9, "low": 0.5 + (0.1 if s % 2 else -0.1)}) for s in seeds]
    img = [_unit("image_aug", s, {"nominal": 0.3, "low": 0.5}) for s in seeds]
    table, comps = vr.summarise_seed_level(real + fa2 + img, ["real", "fa2", "image_aug"], seeds, ["nominal", "low"],
                                           ("fa2",), 50, reps=200)
    by = {(c["variant"], c["setting"]): c for c in comps}
    helps = by["fa2", "nominal"]
    assert helps["p_sign_flip"] == pytest.approx(2 / 1024) and helps["p_holm"] == pytest.approx(4 / 1024)
    assert helps["verdict"] == "helps" and by["fa2", "low"]["verdict"] == "no detectable effect"
    assert by["image_aug", "nominal"]["p_holm"] is None and by["image_aug", "nominal"]["verdict"] is None
    rows = {(r["variant"], r["setting"]): r for r in table}
    assert rows["image_aug", "nominal"]["below_real_worst"] == 1.0 and rows["fa2", "nominal"]["below_real_worst"] == 0.0
    real_rates = rows["real", "nominal"]["per_seed"]
    assert real_rates == [round(0.5 + 0.02 * s, 1) for s in seeds]  # 10 episodes a seed
    assert rows["real", "nominal"]["sd_over_seeds"] == pytest.approx(np.std(real_rates, ddof=1), abs=1e-4)


@pytest.mark.parametrize("flags, named", [
    (["--seeds", "0,1,2,3,4"], "--allow-underpowered"),
    (["--variants", "real,fa9"], "--variants"),
    (["--variants", "fa2"], "real is required"),
    (["--test-seeds", "800010", "800060"], "v1 test"),
    (["--test-seeds", "700010", "700040"], "--validation-seeds"),
    (["--validation-seeds", "10", "40"], "demos"),
    (["--snapshots", "1000,1500"], "--snapshots"),
])
def test_bad_input_is_one_line_naming_the_flag(flags, named, capsys):
    with pytest.raises(SystemExit):
        v2.parse_args(flags)
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert named in err and "error" in err


def test_the_protocol_is_twelve_preregistered_seeds_and_states_its_power():
    _, args = v2.parse_args([])
    assert args.seeds == list(range(12)) and args.test_seeds == (900_000, 900_050)
    _, few = v2.parse_args(["--seeds", "0,1,2", "--allow-underpowered"])
    assert few.seeds == [0, 1, 2]


def test_a_unit_whose_episode_raised_is_written_to_failed_and_stops_the_grid_naming_it(tmp_path, monkeypatch):
    from controltac_il.app import EvaluationError
    from controltac_il.app.experiment import snapshot_path

    torch.manual_seed(0)
    save_checkpoint(snapshot_path(tmp_path / "policies" / "fa2-s3", 2), ACT(tiny_config()))

    def call(self, observation):
        raise RuntimeError("the policy crashed")

    monkeypatch.setattr(ACTPolicy, "__call__", call)
    unit = {"id": "test-fa2-s3-step2", "kind": "test", "variant": "fa2", "seed": 3, "step": 2}
    ctx = {"runs": str(tmp_path), "test_seeds": (900_000, 900_002), "settings": v2.SETTINGS, "signature": "abc"}
    with pytest.raises(EvaluationError, match=r"^unit test-fa2-s3-step2 \(nominal\): 2 of 2 episodes raised"):
        v2.run_unit(unit, ctx)
    failed = json.loads((tmp_path / "failed" / "test-fa2-s3-step2.json").read_text())
    assert [e["seed"] for e in failed["errors"]] == [900_000, 900_001] and "crashed" in failed["errors"][0]["error"]
    assert not (tmp_path / "units").exists()  # nothing counted


def test_wall_time_adds_up_across_a_stopped_and_a_resumed_invocation(tmp_path):
    from benchmarks.touch_il_verdict import WallTime

    t = [1000.0]
    first = WallTime(tmp_path, resume=False, clock=lambda: t[0])
    t[0] += 100.0
    assert first.now()["this_invocation"] == 100.0  # saved; then the invocation is stopped
    second = WallTime(tmp_path, resume=True, clock=lambda: t[0])  # picks the stopped one up from its running file
    t[0] += 50.0
    assert second.now() == {"this_invocation": 50.0, "earlier_invocations": [100.0], "total": 150.0}
    second.finish()
    assert WallTime(tmp_path, resume=True, clock=lambda: t[0]).history == [100.0, 50.0]
    assert WallTime(tmp_path, resume=False).history == []  # a new grid starts from zero
