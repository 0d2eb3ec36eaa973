"""benchmarks.calibration_rule: each candidate level scored by ``decide`` itself, the protocol's choice, a test
split refused until the validation is complete and its level shipped, and a results file never rewritten or mixed.

The cases' runner (``run_cases``: a calibration of minutes each) is replaced by one that hands over given rows;
everything after it is the benchmark's own code."""

import json

import pytest

from benchmarks import calibration_rule as rule
from benchmarks.calibration_rule import LEVELS, choose, level_scores, main
from controltac_il.calibrate.decision import decide
from controltac_il.cli import RunFault

# seven grasps read well, three of one object 1.3x the constant's error: the 95 % and 90 % intervals reach 1, the
# 80 % one does not
BORDERLINE = [{"grasp": g, "frames": 5, "mae_n": r, "constant_mae_n": 1.0, "ratio": r}
              for g, r in enumerate([0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.3, 1.3, 1.3])]


def case(test_ratio: float, draw: int = 3, level: float = 0.95) -> dict:
    """A held-out-object case whose held-out grasp rows are BORDERLINE, decided by calibrate at ``level``, whose
    test MAE ratio is ``test_ratio``."""
    return {"sensor": "unseen_00/three_light", "draw": draw, "cv_per_grasp": BORDERLINE,
            "use_estimator": decide(BORDERLINE, level)["use"], "calibrated_ratio": test_ratio,
            "decision_right": decide(BORDERLINE, level)["use"] == (test_ratio < 1), "generator_calibrated_ratio": 0.4,
            "minutes": 9.0}


def test_a_lower_level_uses_an_estimator_a_higher_one_declines():
    assert not decide(BORDERLINE, 0.95)["use"] and not decide(BORDERLINE, 0.90)["use"]
    d = decide(BORDERLINE, 0.80)
    assert d["use"] and d["interval"][1] < 1 and "80% interval" in d["why"]


def test_each_level_is_scored_by_where_its_decision_meets_the_test():
    """A case that beats the constant on the new objects is missed at 95 and 90 %, used at 80 %; one that loses
    is a false use at 80 %."""
    scores = {s["level"]: s for s in level_scores([case(0.5), case(1.2)])}
    assert {k: (s["decision_accuracy"], s["false_uses"], s["missed_uses"], s["used"]) for k, s in scores.items()} == {
        0.95: (0.5, 0, 1, 0), 0.90: (0.5, 0, 1, 0), 0.80: (0.5, 1, 0, 2)}
    assert tuple(scores) == LEVELS


@pytest.mark.parametrize("tests, chosen", [
    ([0.5], 0.80),             # only the 80 % level is right: chosen
    ([0.5, 1.2], 0.95),        # equal accuracy, 80 % falsely uses once: the cautious levels tie, the higher wins
    ([0.5, 0.5, 1.2], 0.95),   # 80 % is more accurate (2/3 against 1/3) but its false use rules it out
    ([1.2], 0.95),             # every level declining rightly: the highest
])
def test_the_choice_is_fewest_false_uses_then_accuracy_then_the_higher_level(tests, chosen):
    assert choose(level_scores([case(t) for t in tests])) == chosen


def run(tmp_path, monkeypatch, split: str, rows: list[dict], *extra: str) -> dict:
    """``main`` --quick (one sensor, one draw) on ``tmp_path/rule.json``, its runner handing over ``rows``."""
    def runner(cases, args, work, on_row):
        for row in rows:
            on_row(row)
    monkeypatch.setattr(rule, "run_cases", runner)
    return main(["--split", split, "--out", str(tmp_path / "rule.json"), "--quick", *extra])


def test_validation_chooses_and_a_test_at_the_shipped_choice_keeps_the_validation(tmp_path, monkeypatch):
    monkeypatch.setattr(rule, "LEVEL", 0.95)
    assert run(tmp_path, monkeypatch, "validation", [case(1.2)])["chosen_level"] == 0.95
    validation = json.loads((tmp_path / "rule.json").read_text())["validation"]
    out = run(tmp_path, monkeypatch, "test", [case(1.1, draw=6)])
    assert out["level"] == 0.95 and out["figures"]["decision_accuracy"] == 1.0 and len(out["levels"]) == 3
    doc = json.loads((tmp_path / "rule.json").read_text())
    assert doc["validation"] == validation and doc["test"]["rows"][0]["draw"] == 6


def test_the_test_is_refused_until_the_validations_choice_ships(tmp_path, monkeypatch):
    monkeypatch.setattr(rule, "LEVEL", 0.95)
    run(tmp_path, monkeypatch, "validation", [case(0.5)])
    with pytest.raises(ValueError, match="validation chose level 0.8; ship it as controltac_il.calibrate.decision"):
        run(tmp_path, monkeypatch, "test", [])
    assert "test" not in json.loads((tmp_path / "rule.json").read_text())


def test_the_test_is_refused_without_a_complete_validation_in_its_settings(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="no validation cases"):
        run(tmp_path, monkeypatch, "test", [])
    run(tmp_path, monkeypatch, "validation", [case(1.2)], "--seed", "41")
    with pytest.raises(ValueError, match="differ from the validation's"):
        run(tmp_path, monkeypatch, "test", [])
    assert rule.cases("validation", [(0, "three_light"), (1, "three_light_rot")], [case(1.2)], quick=False) == [
        ("unseen_01/three_light_rot", 1, "three_light_rot", 3), *[
            (f"unseen_0{i}/{o}", i, o, d) for d in (4, 5) for i, o in ((0, "three_light"), (1, "three_light_rot"))]]


def test_a_split_in_the_file_is_neither_rewritten_nor_resumed_in_other_settings(tmp_path, monkeypatch):
    run(tmp_path, monkeypatch, "validation", [case(1.2)])
    before = (tmp_path / "rule.json").read_text()
    with pytest.raises(ValueError, match="already holds 1 validation cases: --resume"):
        run(tmp_path, monkeypatch, "validation", [])
    with pytest.raises(ValueError, match=r"were run in .*'seed': 40.*not .*'seed': 41"):
        run(tmp_path, monkeypatch, "validation", [], "--resume", "--seed", "41")
    assert (tmp_path / "rule.json").read_text() == before
    assert run(tmp_path, monkeypatch, "validation", [], "--resume")["rows"] == [case(1.2)]


def test_validation_is_frozen_once_the_test_has_cases_and_other_files_are_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(rule, "LEVEL", 0.95)
    run(tmp_path, monkeypatch, "validation", [case(1.2)])
    run(tmp_path, monkeypatch, "test", [case(1.1, draw=6)])
    with pytest.raises(ValueError, match="the test has cases"):
        run(tmp_path, monkeypatch, "validation", [], "--resume")
    (tmp_path / "rule.json").write_text(json.dumps({"benchmark": "calibration", "rows": []}))
    with pytest.raises(ValueError, match="is not a calibration_rule results file"):
        run(tmp_path, monkeypatch, "validation", [])


def test_a_case_whose_decision_decide_does_not_reproduce_is_refused(tmp_path, monkeypatch):
    """calibrate used the estimator where decide at the shipped level on the same rows declines: the other levels'
    scores would not be of calibrate's rule."""
    monkeypatch.setattr(rule, "LEVEL", 0.95)
    with pytest.raises(RunFault, match="draw 3: decide at level 0.95 does not reproduce calibrate's decision"):
        run(tmp_path, monkeypatch, "validation", [case(1.2, level=0.80)])


@pytest.mark.parametrize("flags, says", [(["--k", "2"], "--k: expected an int >= 3"), (["--jobs", "0"], "--jobs"),
                                         (["--size", "0", "0"], "--size"), (["--device", "abacus"], "--device")])
def test_options_no_case_can_run_with_are_refused_by_flag_before_any_case(tmp_path, capsys, flags, says):
    with pytest.raises(SystemExit) as exc:
        rule.parse(["--split", "validation", "--out", str(tmp_path / "r.json"), *flags])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and says in err[0] and not (tmp_path / "r.json").exists()


def _rendered(monkeypatch, validation_rows: list[dict], test_rows: list[dict] | None = None) -> str:
    """``docs_figures.calibration_rule`` over a results file made of these rows."""
    from benchmarks import docs_figures
    from benchmarks import figure_text as ft

    machine = {"cpu": "AMD EPYC", "cores": 2, "git_commit": "abc1234", "date_utc": "2026-11-29T00:00:00"}
    rows = [dict(r, cv_ratio=0.9, cv_wins=7, cv_grasps=10) for r in validation_rows]
    doc = {"benchmark": "calibration_rule", "protocol": {"levels": list(LEVELS), "splits": rule.SPLITS},
           "validation": {"rows": rows, "levels": level_scores(rows), "chosen_level": choose(level_scores(rows)),
                          "machine": machine}}
    if test_rows:
        test = [dict(r, cv_ratio=0.9, cv_wins=7, cv_grasps=10) for r in test_rows]
        doc["test"] = {"rows": test, "levels": level_scores(test), "level": 0.80, "machine": machine,
                       "figures": rule.heldout_summary(test)}
    monkeypatch.setattr(ft, "load", lambda name: doc)
    return docs_figures.calibration_rule()


def test_the_rendered_table_gives_each_levels_decision_and_marks_the_choice_only_once_validation_is_complete(
        monkeypatch):
    partial = _rendered(monkeypatch, [case(0.5)])
    assert "| validation | `unseen_00/three_light` | 3 | 0.90× |" in partial
    assert "| declined / declined / used | 0.50× | yes | 9.0 |" in partial
    assert "**80%**" not in partial and "Validation: 1 of 9 cases. Test: 0 of 9 cases." in partial
    full = _rendered(monkeypatch, [case(0.5, draw=d) for d in (3, 4, 5) for _ in range(3)],
                     [case(1.2, draw=6, level=0.80)])
    assert "| validation | **80%** | 100% | 0 | 0 | 9 |" in full and "| test | **80%** |" not in full
    assert "chose the 80% level. Test: 1 of 9 cases at the 80% level: decision right in **0%**" in full
    assert "| test | `unseen_00/three_light` | 6 | 0.90× |" in full and "| **no** |" in full


def test_the_readme_row_quotes_the_test_split_only_once_it_is_complete():
    from benchmarks.docs_figures import calibration_row

    cal = {"rows": [{"sensor": "unseen_00/three_light", "cal_frames": 50, "calibrated_ratio": 0.4,
                     "generator_calibrated_ratio": 0.3}],
           "mean": {"calibrated_ratio": 0.4, "generator_calibrated_ratio": 0.3, "minutes": 7.0},
           "targets": {"estimator_ratio": 0.5, "generator_ratio": 0.35}}
    src = {"calibration.json": "`calibration.json`", "calibration_rule.json": "`calibration_rule.json`"}
    test = [case(0.5, draw=d, level=0.80) for d in (6, 7, 8) for _ in range(3)]
    doc = {"protocol": {"splits": dict(rule.SPLITS)}, "validation": {"rows": test},
           "test": {"rows": test[:8], "level": 0.80, "figures": rule.heldout_summary(test[:8])}}
    partial = calibration_row(cal, doc, src)
    assert "tested once" not in partial[1] and partial[-1] == "`calibration.json`"
    doc["test"].update(rows=test, figures=rule.heldout_summary(test))
    full = calibration_row(cal, doc, src)
    assert full[1].endswith("; its 80% level, chosen on 9 other cases and tested once on 9 more: right in 100% (9 of 9, "
                            "Wilson 95 % 70–100 %; target ≥ 90%), the estimator where used 0.50× the constant's, "
                            "generator 0.40×")
    assert full[-1] == "`calibration.json`, `calibration_rule.json`"
