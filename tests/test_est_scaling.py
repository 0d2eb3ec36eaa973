"""Data-scaling benchmark: subset and generation plans, setup validation, a quick run (slow)."""

import json

import numpy as np
import pytest

from benchmarks.force_scaling import ScalingSetup, generation_plan, subset_rows

GROUPS = {("a", 0): [0, 1, 2, 3, 4, 5], ("a", 1): [6, 7, 8, 9, 10, 11], ("b", 0): [12, 13, 14, 15, 16, 17]}


def test_subset_keeps_every_pose_with_fewer_forces():
    rows = subset_rows(GROUPS, 2)
    assert rows == [0, 1, 6, 7, 12, 13]
    assert subset_rows(GROUPS, 6) == list(range(18))


def test_generation_plan_targets_exactly_the_withheld_rows_from_same_pose():
    refs, targets = generation_plan(GROUPS, 2)
    assert sorted(targets.tolist()) == sorted(set(range(18)) - set(subset_rows(GROUPS, 2)))
    pose_of = {i: key for key, rows in GROUPS.items() for i in rows}
    kept = set(subset_rows(GROUPS, 2))
    for r, t in zip(refs, targets):
        assert r in kept and pose_of[r] == pose_of[t]
    # references are used evenly: each kept frame serves 2 of the 4 withheld frames of its pose
    assert sorted(np.bincount(refs, minlength=18)[sorted(kept)].tolist()) == [2] * 6


def test_setup_validation():
    with pytest.raises(ValueError, match="keep"):
        ScalingSetup(forces_per_pose=6, keep=(2, 7))
    with pytest.raises(ValueError, match="reference_keep"):
        ScalingSetup(forces_per_pose=6, keep=(6,), reference_keep=6)
    with pytest.raises(ValueError, match="seeds"):
        ScalingSetup(seeds=())
    assert ScalingSetup(keep=(9, 1, 3)).keep == (1, 3, 9)


@pytest.mark.slow
def test_quick_benchmark_runs_end_to_end(tmp_path):
    from benchmarks.force_scaling import main

    doc = main(["--quick", "--out", str(tmp_path / "fs.json"), "--work-dir", str(tmp_path / "work"),
                "--no-progress", "--steps", "10"])
    saved = json.loads((tmp_path / "fs.json").read_text())
    assert (tmp_path / "fs.png").stat().st_size > 0
    kinds = [r["kind"] for r in saved["rows"]]
    assert kinds[:2] == ["real", "real"] and "third+copy" in kinds and "third+generated" in kinds
    assert saved["rows"] == doc["rows"]
    full = next(r for r in saved["rows"] if r["row"] == "(a) real 6/6")
    assert full["train_images"] == 6 * 3 * 6 and full["test_images"] == 6 * 2 * 6
