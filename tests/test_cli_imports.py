"""Every CLI answers ``--help`` without importing torch, diffusers or MuJoCo: behaviour, checked in a
fresh interpreter's ``sys.modules``, not a time. The heavy modules are imported inside the jobs."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "diffusers", "mujoco", "cv2", "h5py", "pyarrow", "matplotlib")
PROBE = """
import json, runpy, sys
sys.argv = [{prog!r}, *{args!r}, "--help"]
try:
    runpy.{run}({target!r}, run_name="__main__"{alter})
except SystemExit as exc:
    code = exc.code
else:
    code = None
print(json.dumps({{"code": code, "heavy": sorted(m for m in {heavy!r} if m in sys.modules)}}))
"""
CLIS = [("deploy_policy.py", "run_path", ()), ("train_act.py", "run_path", ()),
        ("controltac_il.calibrate", "run_module", ("record",)),
        *(("controltac_il.generator.training", "run_module", (stage,)) for stage in ("stage1", "stage2")),
        *((m, "run_module", ()) for m in ("controltac_il", "controltac_il.augment", "controltac_il.calibrate",
                                          "controltac_il.generator.training",
                                          "controltac_il.estimators.train", "controltac_il.tactile.dataset",
                                          "controltac_il.sign", "envs.collect"))]


@pytest.mark.parametrize("target, run, args", CLIS, ids=[" ".join((c[0], *c[2])) for c in CLIS])
def test_help_imports_no_heavy_module(target, run, args):
    code = PROBE.format(prog=target, args=args, run=run, target=str(REPO / target) if run == "run_path" else target,
                        alter=", alter_sys=True" if run == "run_module" else "", heavy=HEAVY)
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    lines = out.stdout.strip().splitlines()
    assert out.returncode == 0 and lines, out.stderr[-2000:]
    got = json.loads(lines[-1])
    assert got["code"] in (0, None) and "usage" in out.stdout, out.stdout[-500:]
    assert got["heavy"] == [], f"{target} --help imported {got['heavy']}"


def test_progress_bars_stay_off_a_log_file(tmp_path):
    """A CLI whose output goes to a file (not a terminal) writes no carriage-return progress updates."""
    log = tmp_path / "log"
    with log.open("w") as f:
        out = subprocess.run([sys.executable, "-m", "envs.collect", "--episodes", "2", "--out", str(tmp_path / "demos"),
                              "--cameras", "--no-tactile"], cwd=REPO, stdout=f, stderr=subprocess.STDOUT, timeout=300)
    text = log.read_text()
    assert out.returncode == 0, text[-2000:]
    assert "\r" not in text and "wrote 2 episodes" in text


USAGE_PROBE = """
import contextlib, io, json, runpy, sys
out = {{}}
for target, run, args in {clis!r}:
    sys.argv = [target, *args, "--no-such-flag"]
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            getattr(runpy, run)(target if run == "run_module" else {repo!r} + "/" + target, run_name="__main__",
                                **({{"alter_sys": True}} if run == "run_module" else {{}}))
        code = None
    except SystemExit as exc:
        code = exc.code
    out[" ".join((target, *args))] = [code, err.getvalue()]
print(json.dumps(out))
"""


def test_a_usage_error_is_one_line_and_exit_2():
    """A usage error (here an unknown flag, or the required flags it lacks) is ``PROG: error: ... (see --help)`` on
    one line and exit status 2 for every CLI (argparse's own error prints the usage block first)."""
    code = USAGE_PROBE.format(clis=CLIS, repo=str(REPO))
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert len(got) == len(CLIS)
    bad = {cli: (c, err) for cli, (c, err) in got.items()
           if c != 2 or len(err.strip().splitlines()) != 1 or ": error: " not in err or "(see --help)" not in err}
    assert bad == {}
