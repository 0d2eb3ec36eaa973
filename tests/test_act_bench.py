"""The ACT benchmark never reports a policy trained with another generator as this run's."""

import json

import pytest

from benchmarks import act as bench
from controltac_il.generator.checkpoint import checkpoint_hash
from controltac_il.generator.shipped import locate_checkpoint


def _fake_run(folder, augment):
    (folder / "last").mkdir(parents=True)
    (folder / "last" / "config.json").write_text(json.dumps({"meta": {"step": 4000, "augment": augment}}))


def test_a_policy_trained_with_another_generator_is_refused_by_name(tmp_path, capsys):
    now = {"kind": "force", "copies": 1, "generator": "shipped",
           "generator_hash": checkpoint_hash(locate_checkpoint(None)), "seed": 0, "steps": None}
    _fake_run(tmp_path / "real", None)
    _fake_run(tmp_path / "fa1", {**now, "generator_hash": "0123456789abcdef", "summary": {"clamped": 1}})
    before = (tmp_path / "fa1" / "last" / "config.json").read_bytes()
    with pytest.raises(SystemExit) as exc:
        bench.main(["--runs", str(tmp_path), "--variants", "real,fa1"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"--runs: {tmp_path / 'fa1'} was trained with different augmentation" in err
    assert f"generator_hash: '0123456789abcdef' -> '{now['generator_hash']}'" in err
    assert (tmp_path / "fa1" / "last" / "config.json").read_bytes() == before  # left as it was


def test_only_runs_with_other_settings_are_stale(tmp_path):
    now = {"kind": "force", "copies": 2, "generator": "shipped",
           "generator_hash": checkpoint_hash(locate_checkpoint(None)), "seed": 0, "steps": None}
    _fake_run(tmp_path / "fa2", {**now, "summary": {"clamped": 7}})  # counts differ: not a setting
    _fake_run(tmp_path / "real", None)
    assert bench.stale_runs(tmp_path, ["real", "fa2", "fa4"], None) == []  # fa4 not trained yet: fine
    _fake_run(tmp_path / "fa1", {**now, "copies": 2, "seed": 3})
    assert bench.stale_runs(tmp_path, ["real", "fa1", "fa2"], None) == [
        f"{tmp_path / 'fa1'} was trained with different augmentation (copies: 2 -> 1, seed: 3 -> 0)"]
