"""The calibration decision's interval level: chosen on new grasps, tested once on others.

    python -m benchmarks.calibration_rule --split validation --out benchmarks/results/calibration_rule.json
    python -m benchmarks.calibration_rule --split test --out benchmarks/results/calibration_rule.json

``calibrate`` uses its estimator for unlabelled frames only when the upper end of a bootstrap interval of its
held-out Fz MAE ÷ the constant's is below 1 and it wins on most held-out grasps (``decide`` in
``controltac_il.calibrate.decision``). The interval's level is the rule's one lever. On ``benchmarks.calibration``'s
held-out-object cases (draws 0-2) the 95 % level declined one estimator that beat the constant on the new objects;
those cases showed the miss, so they cannot choose the level. This benchmark chooses it by a protocol fixed before
any of its cases ran:

- **Cases:** ``benchmarks.calibration``'s held-out-object cases (its sensors, held-out objects, seed and settings)
  at draws it never ran, so new grasps: ``SPLITS`` (validation draws 3-5, test draws 6-8; 9 cases each).
- **Candidates:** ``LEVELS``, each applied by ``decide`` itself to a case's leave-one-grasp-out rows.
- **Choice, on validation only:** the fewest false uses (the estimator used where it loses to the constant on the
  new objects: the harmful error), then the highest decision accuracy, then the higher level. The levels share
  their bootstrap resamples and the wins condition, so a lower level only adds uses to a higher one's: the choice
  is, of the levels that add no false use to 95 %'s, the one that adds the most right uses; 95 % where none adds one.
- **Test, once:** refused until validation is complete, in the same case settings, and its choice ships as
  ``decision.LEVEL``, so that it scores ``calibrate``'s own decisions against ``benchmarks.calibration``'s targets
  (every level's scores beside them, chosen from by nothing). Validation is refused once the test has cases.

Each case is saved as it finishes; ``--resume`` adds the split's missing cases in the same settings.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.calibration import (add_options, check_options, heldout_summary, quick_settings, run_cases,
                                    todo_cases)
from benchmarks.common import base_parser, machine_info, print_table, write_results
from controltac_il.calibrate.decision import LEVEL, decide
from controltac_il.cli import RunFault

LEVELS = (0.95, 0.90, 0.80)  # 0.95: the level before this protocol
SPLITS = {"validation": (3, 4, 5), "test": (6, 7, 8)}  # draws of benchmarks.calibration's held-out setting
# the settings that define a case: every case of both splits is run in the same ones
CASE_SETTINGS = ("k", "test_grasps", "ae_steps", "dit_steps", "seed", "size", "quick")

PROG = "python -m benchmarks.calibration_rule"


def level_scores(rows: list[dict]) -> list[dict]:
    """Per candidate level, over the cases' held-out grasp rows (``cv_per_grasp``): the decision's accuracy (right:
    used exactly where the test MAE beats the constant's), its false uses, missed uses and uses."""
    beats = np.array([r["calibrated_ratio"] < 1.0 for r in rows], dtype=bool)
    scores = []
    for level in LEVELS:
        use = np.array([decide(r["cv_per_grasp"], level)["use"] for r in rows], dtype=bool)
        scores.append({"level": level, "decision_accuracy": float(np.mean(use == beats)),
                       "false_uses": int(np.sum(use & ~beats)), "missed_uses": int(np.sum(~use & beats)),
                       "used": int(use.sum())})
    return scores


def choose(scores: list[dict]) -> float:
    """The protocol's choice: fewest false uses, then the highest accuracy, then the higher level."""
    return min(scores, key=lambda s: (s["false_uses"], -s["decision_accuracy"], -s["level"]))["level"]


def cases(split: str, sensors, rows: list[dict], quick: bool) -> list[tuple]:
    """The split's (name, index, optics, draw) cases not yet in ``rows``, draw by draw (``--quick``: its first)."""
    return todo_cases(sensors, SPLITS[split][:1] if quick else SPLITS[split], rows)


def case_settings(settings: dict) -> dict:
    """The ``CASE_SETTINGS`` of a run's settings, as JSON holds them (a tuple reads back as a list)."""
    return json.loads(json.dumps({k: settings[k] for k in CASE_SETTINGS}))


def load(args) -> dict:
    """The results file so far; ValueError where it is another benchmark's, or where this run would rewrite its
    split's cases, add cases in other settings, or change a validation whose choice the test has used."""
    doc = json.loads(args.out.read_text()) if args.out.is_file() else {}
    if doc and (not isinstance(doc, dict) or doc.get("benchmark") != "calibration_rule"):
        raise ValueError(f"{args.out} is not a calibration_rule results file: choose another --out")
    split = doc.get(args.split, {})
    if split.get("rows") and not args.resume:
        raise ValueError(f"{args.out} already holds {len(split['rows'])} {args.split} cases: --resume (in the same "
                         "settings) to add the missing ones")
    if split.get("rows") and case_settings(split["settings"]) != case_settings(vars(args)):
        raise ValueError(f"{args.out}: the {args.split} cases were run in {case_settings(split['settings'])}, not "
                         f"{case_settings(vars(args))}")
    if args.split == "validation" and doc.get("test", {}).get("rows"):
        raise ValueError(f"{args.out}: the test has cases; the validation that chose its level stays as it is")
    return doc


def validation_choice(doc: dict, args, sensors) -> float:
    """The level the complete validation split chose; ValueError naming what is missing or differs."""
    val = doc.get("validation")
    if not val:
        raise ValueError(f"{args.out}: no validation cases; run --split validation first")
    if case_settings(val["settings"]) != case_settings(vars(args)):
        raise ValueError(f"{args.out}: the test's case settings {case_settings(vars(args))} differ from the "
                         f"validation's {case_settings(val['settings'])}")
    if cases("validation", sensors, val["rows"], args.quick):
        raise ValueError(f"{args.out}: the validation split is not complete; --split validation --resume first")
    level = choose(level_scores(val["rows"]))
    if level != val["chosen_level"]:
        raise ValueError(f"the validation cases now choose level {level}, where they chose {val['chosen_level']}: "
                         "decide changed since they ran")
    if level != LEVEL:
        raise ValueError(f"validation chose level {level}; ship it as controltac_il.calibrate.decision.LEVEL "
                         f"(now {LEVEL}) before the test")
    return level


def split_figures(split: str, rows: list[dict], args, t0: float) -> dict:
    """The split's document: its cases, settings and machine, every level's scores, and validation's choice or the
    test's figures of ``calibrate``'s own decisions."""
    out = {"settings": {k: v for k, v in vars(args).items() if k not in ("out", "split")}, "machine": machine_info(),
           "wall_s_this_invocation": round(time.perf_counter() - t0, 1), "rows": rows,
           "levels": level_scores(rows) if rows else []}
    if split == "validation":
        out["chosen_level"] = choose(out["levels"]) if rows else None
    else:
        out.update(level=LEVEL, figures=heldout_summary(rows) if rows else None)
    return out


def checked(row: dict) -> dict:
    """``row``, once ``decide`` at ``LEVEL`` on its held-out grasp rows reproduces ``calibrate``'s decision: else the
    scores of the other levels would not be of the rule ``calibrate`` runs."""
    if decide(row["cv_per_grasp"], LEVEL)["use"] != row["use_estimator"]:
        raise RunFault(f"{row['sensor']} draw {row['draw']}: decide at level {LEVEL} does not reproduce "
                         f"calibrate's decision ({row['use_estimator']}) from its held-out grasp rows")
    return row


def parse(argv):
    p = base_parser(PROG, __doc__.split("\n\n")[0])
    add_options(p)
    p.add_argument("--split", choices=tuple(SPLITS), required=True,
                   help="validation: score every level on draws 3-5 and choose; test: the chosen level once, "
                        "on draws 6-8 (refused until validation is complete and the level shipped)")
    args = p.parse_args(argv)
    if args.out is None:
        p.error("--out is required: the validation's choice and the test live in one file")
    check_options(p, args)
    return args


def main(argv=None) -> dict:
    args = parse(argv)
    sensors, doc = quick_settings(args), load(args)
    if args.split == "test":
        validation_choice(doc, args, sensors)
    rows, t0 = list(doc.get(args.split, {}).get("rows", [])), time.perf_counter()

    def save(row: dict) -> None:
        rows.append(checked(row))
        print_table([row], ["sensor", "draw", "cv_ratio", "use_estimator", "calibrated_ratio", "minutes"])
        doc.update({"benchmark": "calibration_rule", "protocol": {"levels": LEVELS, "splits": SPLITS},
                    args.split: split_figures(args.split, rows, args, t0)})
        write_results(args.out, {k: v for k, v in doc.items() if k != "machine"})

    with tempfile.TemporaryDirectory(prefix="calibration-rule-") as work:
        run_cases(cases(args.split, sensors, rows, args.quick), args, Path(work), save)
    figures = split_figures(args.split, rows, args, t0)
    print_table(figures["levels"], ["level", "decision_accuracy", "false_uses", "missed_uses", "used"],
                title=f"{args.split}: {len(rows)} cases" + ("" if args.split == "validation" else
                                                            f" (calibrate's level {LEVEL}; the others chose nothing)"))
    return figures


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
