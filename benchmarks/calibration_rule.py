"""The calibration decision's interval level: chosen on fresh draws, tested once on others.

    python -m benchmarks.calibration_rule --split validation --out benchmarks/results/calibration_rule.json
    python -m benchmarks.calibration_rule --split test --out benchmarks/results/calibration_rule.json

``calibrate`` uses its estimator for unlabelled frames only when the upper end of a bootstrap interval of its
held-out Fz MAE ÷ the constant's is below 1 and it wins on most held-out grasps (``controltac_il.calibrate.
decision``). The interval's level is the rule's one lever. On ``benchmarks.calibration``'s held-out-object cases
(draws 0-2) the shipped 95 % declined one estimator that beat the constant on the new objects; those cases showed
the miss, so they cannot choose the level. This benchmark chooses it by a protocol fixed before any of its cases ran:

- **Cases:** ``benchmarks.calibration``'s held-out-object cases (its sensors, seed and settings) at draws it never
  ran: ``SPLITS`` (validation draws 3-5, test draws 6-8; 9 cases each).
- **Candidates:** ``LEVELS``, each applied to a case's leave-one-grasp-out rows by ``decide`` itself.
- **Choice, on validation only:** the fewest false uses (the estimator used where it loses to the constant on the
  new objects: the harmful error), then the highest decision accuracy; ties go to the higher level, the cautious one.
- **Test, once:** refused until validation is complete and ``decision.LEVEL`` is the chosen level, so that it scores
  ``calibrate``'s own decisions: their accuracy, false and missed uses, against ``benchmarks.calibration``'s targets.

Each case is saved as it finishes; ``--resume`` keeps the split's cases already in ``--out``.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.calibration import add_options, heldout_summary, quick_settings, run_cases
from benchmarks.common import base_parser, print_table, write_results
from controltac_il.calibrate.decision import LEVEL, decide

LEVELS = (0.95, 0.90, 0.80)  # the shipped level first
SPLITS = {"validation": (3, 4, 5), "test": (6, 7, 8)}  # draws of benchmarks.calibration's held-out setting
# the settings that define a case: the test must use the validation's
CASE_SETTINGS = ("k", "test_grasps", "ae_steps", "dit_steps", "seed", "size", "quick")


def level_scores(rows: list[dict]) -> list[dict]:
    """Per candidate level, over the cases' leave-one-grasp-out rows (``cv_per_grasp``): the decision's accuracy
    (right: used exactly where the test MAE beats the constant's), its false uses, missed uses and uses."""
    beats = np.array([r["calibrated_ratio"] < 1.0 for r in rows])
    scores = []
    for level in LEVELS:
        use = np.array([decide(r["cv_per_grasp"], level)["use"] for r in rows])
        scores.append({"level": level, "decision_accuracy": float(np.mean(use == beats)),
                       "false_uses": int(np.sum(use & ~beats)), "missed_uses": int(np.sum(~use & beats)),
                       "used": int(use.sum())})
    return scores


def choose(scores: list[dict]) -> float:
    """The protocol's choice: fewest false uses, then the highest accuracy, then the highest level."""
    return min(scores, key=lambda s: (s["false_uses"], -s["decision_accuracy"], -s["level"]))["level"]


def cases(split: str, sensors, rows: list[dict], quick: bool) -> list[tuple]:
    """The split's (name, index, optics, draw) cases not yet in ``rows``, draw by draw."""
    draws = SPLITS[split][:1] if quick else SPLITS[split]
    todo = [(f"unseen_{i:02d}/{o}", i, o, d) for d in draws for i, o in sensors]
    return [c for c in todo if not any(r["sensor"] == c[0] and r["draw"] == c[3] for r in rows)]


def validation_choice(doc: dict, args) -> float:
    """The level the complete validation split chose; SystemExit naming what is missing or differs."""
    val = doc.get("validation")
    if not val or cases("validation", quick_settings(args), val["rows"], args.quick):
        raise SystemExit(f"{args.out}: the validation split is not complete; run --split validation first")
    case = {k: v for k, v in vars(args).items() if k in CASE_SETTINGS}
    if {k: val["settings"][k] for k in CASE_SETTINGS} != json.loads(json.dumps(case)):
        raise SystemExit(f"{args.out}: the test's case settings {case} differ from the validation's")
    level = choose(level_scores(val["rows"]))
    if level != LEVEL:
        raise SystemExit(f"validation chose level {level}; ship it as controltac_il.calibrate.decision.LEVEL "
                         f"(now {LEVEL}) before the test")
    return level


def split_figures(split: str, rows: list[dict], args) -> dict:
    """The split's document: its cases, settings, and the level scores (validation) or the decision's figures."""
    out = {"settings": {k: v for k, v in vars(args).items() if k not in ("out", "split")}, "rows": rows}
    if split == "validation":
        out["levels"] = level_scores(rows) if rows else []
        out["chosen_level"] = choose(out["levels"]) if rows else None
    else:
        out["level"] = LEVEL
        out["figures"] = heldout_summary(rows)
    return out


def parse(argv):
    p = base_parser(__doc__.split("\n\n")[0])
    add_options(p)
    p.add_argument("--split", choices=tuple(SPLITS), required=True,
                   help="validation: score every level on draws 3-5 and choose; test: the chosen level once, "
                        "on draws 6-8 (refused until validation is complete and the level shipped)")
    args = p.parse_args(argv)
    if args.out is None:
        p.error("--out is required: the validation's choice and the test live in one file")
    return args


def main(argv=None) -> dict:
    args = parse(argv)
    sensors = quick_settings(args)
    doc = json.loads(args.out.read_text()) if args.out.is_file() else {}
    done = doc.get(args.split, {}).get("rows", [])
    if done and not args.resume:
        raise SystemExit(f"{args.out} already holds {len(done)} {args.split} cases: --resume to keep them")
    if args.split == "test":
        validation_choice(doc, args)
    rows, t0 = list(done), time.perf_counter()

    def save(row: dict) -> None:
        rows.append(row)
        print_table([row], ["sensor", "draw", "cv_ratio", "use_estimator", "calibrated_ratio", "minutes"])
        doc.update({"benchmark": "calibration_rule", "protocol": {"levels": LEVELS, "splits": SPLITS},
                    args.split: split_figures(args.split, rows, args)})
        doc["wall_s_this_invocation"] = round(time.perf_counter() - t0, 1)
        write_results(args.out, {k: v for k, v in doc.items() if k != "machine"})

    with tempfile.TemporaryDirectory(prefix="calibration-rule-") as work:
        run_cases(cases(args.split, sensors, rows, args.quick), args, Path(work), save)
    figures = split_figures(args.split, rows, args)
    table = figures["levels"] if args.split == "validation" else [{"level": LEVEL, **figures["figures"]}]
    print_table(table, ["level", "decision_accuracy", "false_uses", "missed_uses", "used"],
                title=f"{args.split}: {len(rows)} cases")
    return figures


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard("python -m benchmarks.calibration_rule", lambda: main() and 0))
