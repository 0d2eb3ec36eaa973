"""benchmarks.calibration_rule: each candidate level scored by ``decide`` itself, the protocol's choice, and a test
split that is refused until the validation is complete and its level shipped."""

import json

import pytest

from benchmarks.calibration_rule import (LEVELS, choose, level_scores, main, parse, split_figures,
                                         validation_choice)
from benchmarks.calibration import quick_settings
from controltac_il.calibrate.decision import LEVEL, decide

# seven grasps read well, three of one object 1.3x the constant's error: the 95 % and 90 % intervals reach 1, the
# 80 % one does not
BORDERLINE = [{"grasp": g, "frames": 5, "mae_n": r, "constant_mae_n": 1.0, "ratio": r}
              for g, r in enumerate([0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.3, 1.3, 1.3])]


def case(test_ratio: float, draw: int = 3) -> dict:
    """A held-out-object case whose leave-one-grasp-out rows are BORDERLINE and whose test MAE ratio is given."""
    return {"sensor": "unseen_00/three_light", "draw": draw, "cv_per_grasp": BORDERLINE,
            "calibrated_ratio": test_ratio}


def test_a_lower_level_uses_an_estimator_the_shipped_level_declines():
    assert LEVELS[0] == LEVEL and not decide(BORDERLINE, 0.95)["use"] and not decide(BORDERLINE, 0.90)["use"]
    d = decide(BORDERLINE, 0.80)
    assert d["use"] and d["interval"][1] < 1 and "80% interval" in d["why"]


def test_each_level_is_scored_by_where_its_decision_meets_the_test():
    """A case that beats the constant on the new objects is missed at 95 and 90 %, used at 80 %; one that loses
    is a false use at 80 %."""
    scores = {s["level"]: s for s in level_scores([case(0.5), case(1.2)])}
    assert {k: (s["decision_accuracy"], s["false_uses"], s["missed_uses"], s["used"]) for k, s in scores.items()} == {
        0.95: (0.5, 0, 1, 0), 0.90: (0.5, 0, 1, 0), 0.80: (0.5, 1, 0, 2)}


@pytest.mark.parametrize("tests, chosen", [
    ([0.5], 0.80),             # only the 80 % level is right: chosen
    ([0.5, 1.2], 0.95),        # equal accuracy, 80 % falsely uses once: the cautious levels tie, the higher wins
    ([0.5, 0.5, 1.2], 0.95),   # 80 % is more accurate (2/3 against 1/3) but its false use rules it out
    ([1.2], 0.95),             # every level declining rightly: the shipped level
])
def test_the_choice_is_fewest_false_uses_then_accuracy_then_the_higher_level(tests, chosen):
    assert choose(level_scores([case(t) for t in tests])) == chosen


def validation_doc(tmp_path, rows: list[dict], *extra: str) -> tuple[dict, object]:
    """A results file whose validation split holds ``rows``, run with --quick (one sensor, one draw) and ``extra``."""
    out = tmp_path / "rule.json"
    args = parse(["--split", "validation", "--out", str(out), "--quick", *extra])
    quick_settings(args)
    doc = json.loads(json.dumps({"validation": split_figures("validation", rows, args)}))
    out.write_text(json.dumps(doc))
    return doc, parse(["--split", "test", "--out", str(out), "--quick"])


def test_the_test_split_runs_only_with_the_level_the_validation_chose_shipped(tmp_path):
    doc, args = validation_doc(tmp_path, [case(1.2)])
    quick_settings(args)
    assert validation_choice(doc, args) == LEVEL
    doc, args = validation_doc(tmp_path, [case(0.5)])
    quick_settings(args)
    with pytest.raises(SystemExit, match="validation chose level 0.8; ship it as controltac_il.calibrate.decision"):
        validation_choice(doc, args)


def test_the_test_split_is_refused_before_a_complete_validation_or_with_other_settings(tmp_path):
    doc, args = validation_doc(tmp_path, [])
    quick_settings(args)
    with pytest.raises(SystemExit, match="the validation split is not complete"):
        validation_choice(doc, args)
    with pytest.raises(SystemExit, match="the validation split is not complete"):
        validation_choice({}, args)
    doc, args = validation_doc(tmp_path, [case(1.2)], "--seed", "41")
    quick_settings(args)
    with pytest.raises(SystemExit, match="differ from the validation's"):
        validation_choice(doc, args)


def test_a_split_already_in_the_file_is_kept_unless_resumed(tmp_path):
    validation_doc(tmp_path, [case(1.2)])
    before = (tmp_path / "rule.json").read_text()
    with pytest.raises(SystemExit, match="already holds 1 validation cases: --resume to keep them"):
        main(["--split", "validation", "--out", str(tmp_path / "rule.json"), "--quick"])
    assert (tmp_path / "rule.json").read_text() == before
