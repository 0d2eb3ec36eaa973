"""Benchmark provenance: the recorded revision says when the tree differs from the commit; every benchmark's
command line reports a fault as one line and an exit code."""

import ast
import re
import subprocess
from pathlib import Path

import pytest

from benchmarks.common import base_parser, git_revision


def _git(repo, *args):
    subprocess.run(["git", *args], cwd=repo, check=True, capture_output=True)


def test_git_revision_marks_uncommitted_changes_dirty(tmp_path):
    _git(tmp_path, "init", "-q")
    (tmp_path / "weights.txt").write_text("a")
    _git(tmp_path, "add", "weights.txt")
    _git(tmp_path, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "one")
    head = subprocess.run(["git", "rev-parse", "--short=7", "HEAD"], cwd=tmp_path,
                          capture_output=True, text=True, check=True).stdout.strip()
    assert git_revision(tmp_path) == head
    _git(tmp_path, "tag", "v1")  # a tag does not replace the commit
    assert git_revision(tmp_path) == head
    (tmp_path / "weights.txt").write_text("b")
    assert git_revision(tmp_path) == head + "-dirty"


def test_git_revision_outside_a_repository_is_none(tmp_path):
    assert git_revision(tmp_path) is None


def test_a_run_that_saves_as_it_goes_keeps_the_revision_it_started_from(tmp_path, monkeypatch):
    from benchmarks import common

    revisions = iter(["abc1234", "abc1234-dirty"])  # the first save itself dirties a tracked results file
    monkeypatch.setattr(common, "git_revision", lambda path: next(revisions))
    common.machine_info.cache_clear()
    try:
        first = common.write_results(tmp_path / "r.json", {"step": 1})
        second = common.write_results(tmp_path / "r.json", {"step": 2})
    finally:
        common.machine_info.cache_clear()
    assert first["machine"]["git_commit"] == second["machine"]["git_commit"] == "abc1234"
    assert second["step"] == 2


def _main_block_calls(path: Path) -> set[str] | None:
    """Names called in the module's ``if __name__ == "__main__":`` block; None when it has none."""
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.If) and getattr(getattr(node.test, "left", None), "id", None) == "__name__":
            return {getattr(c.func, "id", getattr(c.func, "attr", None)) for c in ast.walk(node) if isinstance(c, ast.Call)}
    return None


def test_every_benchmark_runs_its_main_under_guard():
    """``python -m benchmarks.X`` with a bad option value or file prints ``PROG: error: ...`` and exits 2, not a
    traceback: each entry point wraps main in controltac_il.cli.guard."""
    root = Path(__file__).resolve().parents[1] / "benchmarks"
    entries = {p.relative_to(root).as_posix(): calls for p in root.rglob("*.py")
               if (calls := _main_block_calls(p)) is not None}
    assert len(entries) >= 20
    assert [name for name, calls in entries.items() if "guard" not in calls] == []


def test_every_benchmarks_usage_error_starts_with_the_command_that_runs_it(monkeypatch, capsys):
    """``python -m benchmarks.X --no-such-flag``: one line ``python -m benchmarks.X: error: ...``, exit 2 (not the
    file name argparse would take from sys.argv). Run as ``-m`` runs it, in this process (the libraries the
    benchmarks import are loaded once for all of them)."""
    import runpy
    import sys
    import warnings

    root = Path(__file__).resolve().parents[1] / "benchmarks"
    modules = sorted("benchmarks." + p.relative_to(root).with_suffix("").as_posix().replace("/", ".")
                     .removesuffix(".__main__") for p in root.rglob("*.py") if _main_block_calls(p) is not None)
    got = {}
    for module in modules:
        monkeypatch.setattr(sys, "argv", [module, "--no-such-flag"])
        with warnings.catch_warnings(), pytest.raises(SystemExit) as exc:
            warnings.simplefilter("ignore", RuntimeWarning)  # runpy's note on a module an earlier test imported
            runpy.run_module(module, run_name="__main__", alter_sys=True)
        got[module] = (exc.value.code, capsys.readouterr().err)
    bad = {m: got[m] for m in modules if got[m][0] != 2 or not got[m][1].startswith(f"python -m {m}: error: ")
           or len(got[m][1].strip().splitlines()) != 1}
    assert len(modules) >= 20 and bad == {}


@pytest.mark.parametrize("module, args, says", [
    ("benchmarks.env", ["--seeds", "-1"], "--seeds must be an int >= 1"),  # a division by zero
    ("benchmarks.hardware", ["--policy-ms", "nan"], "--policy-ms must be a finite number"),  # a policy's traceback
    ("benchmarks.hardware", ["--raw-hw", "0", "0"], r"--raw-hw H W must be pixels, each in \[8, 2048\]"),
    ("benchmarks.sensor", ["--real-dir", "/nonexistent/frames"], "--real-dir /nonexistent/frames is not a folder"),
])
def test_a_benchmark_refuses_a_value_it_cannot_run_with_before_it_starts(module, args, says, capsys):
    import importlib

    with pytest.raises(SystemExit) as exc:
        importlib.import_module(module).main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and re.search(says, err[0]), err


def test_every_benchmark_refuses_a_folder_as_out_and_accepts_a_new_file_path(tmp_path, capsys):
    p = base_parser("python -m benchmarks.a", "a benchmark")
    with pytest.raises(SystemExit) as exc:
        p.parse_args(["--out", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and len(err) == 1 and f"{tmp_path} is a folder; expected a JSON file path" in err[0]
    assert p.parse_args(["--out", str(tmp_path / "new" / "r.json")]).out == tmp_path / "new" / "r.json"


def test_timings_skip_the_warm_up_and_quartiles_bracket_the_median():
    """An injected clock: the calls take 1, 2, ..., 9 s after a 100 s warm-up call, which is never timed."""
    from benchmarks.common import median_time, quartiles, timings

    calls, durations = [], [100, *range(1, 10)]

    def clock():  # the time at which the calls made so far have ended
        return float(sum(durations[:len(calls)]))

    def fn():
        calls.append(1)

    assert timings(fn, repeats=9, warmup=1, clock=clock) == [float(d) for d in range(1, 10)]
    calls.clear()
    assert median_time(fn, repeats=9, warmup=1, clock=clock) == 5.0
    assert quartiles(list(range(1, 10))) == (3.0, 7.0)
