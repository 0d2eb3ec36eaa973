"""A runtime fault a user can cause or meet ends a CLI with one line on stderr and an exit code,
never a traceback. The cheap cases, in-process (no training, no scene): an unreachable robot, a setup that does
not fit the policy, an output that cannot be written, Ctrl-C. The whole table, with real processes, training runs
and Ctrl-C sent as a signal: ``python -m benchmarks.robustness --faults``; its judge is checked here too."""

import subprocess
import sys
import types

import pytest
import torch

from act_fixtures import tiny_config
from benchmarks.robustness.harness import CLEAR, SILENT, UNCLEAR, error_lines, judge_fault
from policies.act import ACT, save_checkpoint


SETUP = ("robot: {type: xarm, ip: 127.0.0.1}\n"
         "cameras: {third_view: {device: /dev/video0}, wrist: {device: /dev/video1}}\n"
         "tactile: {left: {device: /dev/video2}, right: {device: /dev/video3}}\n"
         "limits: {workspace_min: [0.2, -0.3, 0.0], workspace_max: [0.6, 0.3, 0.5]}\n")


def one_line(capsys) -> str:
    """The one line on stderr (progress bars aside, as the benchmark's judge reads it)."""
    err = capsys.readouterr().err
    lines = error_lines(err)
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture()
def checkpoint(tmp_path):
    torch.manual_seed(0)
    return save_checkpoint(tmp_path / "ckpt", ACT(tiny_config()))


@pytest.fixture()
def silent_xarm(monkeypatch):
    """The xArm SDK failing as it does when nothing answers; no pre-flight socket (no network in the test)."""
    import hardware.config

    class XArmAPI:
        def __init__(self, ip, **kw):
            raise Exception("connect socket failed")

    monkeypatch.setitem(sys.modules, "xarm.wrapper", types.SimpleNamespace(XArmAPI=XArmAPI))
    monkeypatch.setattr(hardware.config, "CONNECT_TIMEOUT_S", None)


def test_deploy_cli_unreachable_robot_is_one_line_exit_1(checkpoint, tmp_path, capsys, silent_xarm):
    from controltac_il.app import deploy_cli as deploy_policy

    setup = tmp_path / "site.yaml"
    setup.write_text(SETUP)
    assert deploy_policy.main(["--robot", "xarm", "--checkpoint", str(checkpoint), "--config", str(setup)]) == 1
    assert one_line(capsys).startswith(f"deploy_policy.py: robot error: {setup}: xArm 127.0.0.1: cannot connect "
                                       "to the controller (connect socket failed)")


@pytest.mark.parametrize("case, named", [
    ("missing setup", "cannot read the setup file"),
    ("chunk size in the setup", "control.chunk_size: the chunk size is the policy's"),
    ("deadline past the policy's chunk", "control.inference_deadline_s: longer than one chunk of the policy"),
    ("--out in a missing folder", "--out"),
])
def test_deploy_cli_setup_and_output_faults_are_one_line_exit_2(checkpoint, tmp_path, capsys, silent_xarm, case, named):
    from controltac_il.app import deploy_cli as deploy_policy

    setup, out = tmp_path / "site.yaml", []
    if case == "chunk size in the setup":
        setup.write_text(SETUP + "control: {chunk_size: 20}\n")
    elif case == "deadline past the policy's chunk":
        setup.write_text(SETUP + "control: {inference_deadline_s: 1.0}\n")
    elif case == "--out in a missing folder":
        setup.write_text(SETUP)
        out = ["--out", str(tmp_path / "nowhere" / "result.json")]
    assert deploy_policy.main(["--robot", "xarm", "--checkpoint", str(checkpoint), "--config", str(setup), *out]) == 2
    assert named in one_line(capsys)


def test_deploy_cli_ctrl_c_is_one_line_exit_130(checkpoint, capsys, monkeypatch):
    import importlib

    from controltac_il.app import deploy_cli as deploy_policy

    app = importlib.import_module("controltac_il.app.deploy")  # (controltac_il.app.deploy is also the function)

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(app, "evaluate_in_sim", interrupted)
    assert deploy_policy.main(["--robot", "sim", "--checkpoint", str(checkpoint), "--episodes", "1"]) == 130
    assert "interrupted (Ctrl-C)" in one_line(capsys)


def test_main_job_cli_faults_are_one_line(tmp_path, capsys, monkeypatch):
    import controltac_il.app.job as job
    from controltac_il.__main__ import main

    assert main(["--out", str(tmp_path / "out"), "--demos", "0"]) == 2
    assert "--demos: Input should be greater than or equal to 1 (got 0)" in one_line(capsys)
    (tmp_path / "a_file").write_text("the user's")
    assert main(["--out", str(tmp_path / "a_file" / "out"), "--sensor-only"]) == 2
    assert "a_file" in one_line(capsys)
    assert main(["--out", str(tmp_path), "--sensor-only"]) == 2  # the user's folder: a_file is theirs
    assert "holds files this job did not write (a_file)" in one_line(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]

    def interrupted(out):
        raise KeyboardInterrupt

    monkeypatch.setattr(job, "render_contact_sheet", interrupted)
    assert main(["--out", str(tmp_path / "out"), "--sensor-only"]) == 130
    assert "interrupted (Ctrl-C)" in one_line(capsys)


def test_train_cli_unwritable_out_is_one_line_exit_2(tmp_path, capsys):
    from controltac_il.app import train_cli as train_act
    from benchmarks.robustness.harness import demo_episodes

    (tmp_path / "a_file").write_text("the user's")
    data = demo_episodes(tmp_path / "demos", n=2)
    assert train_act.main(["--dataset", str(data), "--out", str(tmp_path / "a_file" / "run"), "--steps", "1",
                           "--batch-size", "2", "--chunk-size", "6"]) == 2
    assert f"{tmp_path / 'a_file'} is a file, so no folder can be made under it" in one_line(capsys)  # before step 1


def test_fault_judge_reads_stderr_as_a_terminal_shows_it():
    bar = "cache:   0%|    | 0/207 [00:02<?, ?frame/s]\rcache:   1%|    | 2/207 [00:03<01:40, 2.0frame/s]"
    res = subprocess.CompletedProcess([], 130, "", bar + "prog: interrupted (Ctrl-C)\n")
    assert error_lines(res.stderr) == ["prog: interrupted (Ctrl-C)"]
    assert judge_fault(res, "interrupted", code=130) == (CLEAR, "exit 130: prog: interrupted (Ctrl-C)",
                                                         {"exit_code": 130, "one_line": True})
    crash = subprocess.CompletedProcess([], 1, "", "Traceback (most recent call last):\n  x\nArmFault: boom\n")
    verdict, detail, outcome = judge_fault(crash)
    assert verdict == UNCLEAR and detail.endswith("ArmFault: boom") and outcome == {"exit_code": 1, "one_line": False}
    assert judge_fault(subprocess.CompletedProcess([], 0, "done", ""))[0] == SILENT
    assert judge_fault(subprocess.CompletedProcess([], 2, "", "prog: error: x\n"), code=1)[0] == UNCLEAR
