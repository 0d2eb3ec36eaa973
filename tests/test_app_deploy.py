"""Deployment through the wiring: checks before motion, Wilson interval, the deploy CLI's errors."""

import math
from pathlib import Path

import pytest
import torch

from act_fixtures import tiny_config
from controltac_il.app.deploy import WallTimed, check_setup, deploy, deploy_on_robot, load_policy
from controltac_il.metrics import wilson_interval
from hardware.config import ConfigError
from hardware.fakes import FAKE_WORKSPACE
from hardware.safety import SafetyLimits
from policies.act import ACT, ACTPolicy, save_checkpoint


def test_wilson_interval_matches_hand_computation():
    # 36 of 50: p = 0.72, z = 1.96 -> centre (0.72 + 1.96^2/100) / (1 + 1.96^2/50), half width below
    z, n, p = 1.959963984540054, 50, 0.72
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    lo, hi = wilson_interval(36, 50)
    assert lo == pytest.approx(centre - half) and hi == pytest.approx(centre + half)
    assert lo == pytest.approx(0.5833, abs=1e-3) and hi == pytest.approx(0.8253, abs=1e-3)
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(10, 10)[1] == pytest.approx(1.0)
    assert wilson_interval(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError, match="successes"):
        wilson_interval(11, 10)


@pytest.fixture()
def checkpoint(tmp_path):
    torch.manual_seed(0)
    return save_checkpoint(tmp_path / "ckpt", ACT(tiny_config()))


def test_check_setup_names_what_is_missing(checkpoint):
    policy = load_policy(checkpoint)
    check_setup(policy, ["third_view", "wrist"], ["left", "right"])
    with pytest.raises(ValueError, match="camera 'wrist'"):
        check_setup(policy, ["third_view"], ["left", "right"])
    with pytest.raises(ValueError, match="tactile sensor 'right'"):
        check_setup(policy, ["third_view", "wrist"], ["left"])
    assert isinstance(load_policy(policy), ACTPolicy)
    torch.manual_seed(0)
    seven = ACTPolicy(ACT(tiny_config(action_dim=7)))
    with pytest.raises(ValueError, match="action_dim is 7; the robot's actions"):
        check_setup(seven, ["third_view", "wrist"], ["left", "right"])


def test_robot_deploy_refuses_a_setup_without_a_camera_before_connecting(checkpoint, tmp_path):
    setup = tmp_path / "setup.yaml"
    # loopback, where no controller listens: reaching the connection would fail
    setup.write_text("robot: {type: xarm, ip: 127.0.0.1}\ngripper: {type: none}\n"
                     "cameras: {third_view: {device: /dev/video0}}\n"
                     "tactile: {left: {device: /dev/video2}, right: {device: /dev/video3}}\n"
                     "limits: {workspace_min: [0.2, -0.3, 0.0], workspace_max: [0.6, 0.3, 0.5]}\n")
    with pytest.raises(ValueError, match="camera 'wrist'"):
        deploy_on_robot("xarm", checkpoint, setup)
    with pytest.raises(ValueError, match="robot.type 'xarm'"):
        deploy_on_robot("ur", checkpoint, setup)


ROBOT = ("robot: {type: xarm, ip: 127.0.0.1}\n"
         "cameras: {third_view: {device: /dev/video0}, wrist: {device: /dev/video1}}\n"
         "tactile: {left: {device: /dev/video2}, right: {device: /dev/video3}}\n"
         "limits: {workspace_min: [0.2, -0.3, 0.0], workspace_max: [0.6, 0.3, 0.5]}\n")


def test_robot_deploy_checks_the_deadline_against_the_policys_chunk_before_connecting(checkpoint, tmp_path,
                                                                                     monkeypatch):
    import hardware.config

    def connect(*a, **k):
        raise AssertionError("nothing may connect before the setup fits the policy")

    monkeypatch.setattr(hardware.config, "build_arm", connect)
    setup = tmp_path / "setup.yaml"
    setup.write_text(ROBOT + "control: {inference_deadline_s: 1.0}\n")  # the tiny policy's chunk: 6 x 0.1 s
    with pytest.raises(ConfigError, match=rf"^{setup}: control\.inference_deadline_s: longer than one chunk of the "
                                          r"policy \(chunk_size 6 x 0\.1 s = 0\.6 s\).*at most 0\.6 s \(got 1\.0\)$"):
        deploy_on_robot("xarm", checkpoint, setup)
    setup.write_text(ROBOT + "control: {chunk_size: 20}\n")  # the policy owns it: never two owners
    with pytest.raises(ConfigError, match=rf"^{setup}: control\.chunk_size: the chunk size is the policy's"):
        deploy_on_robot("xarm", checkpoint, setup)


def test_deploy_runs_the_loop_with_the_policys_chunk(checkpoint):
    from hardware.config import Setup
    from hardware.control_loop import LoopTiming
    from hardware.fakes import FakeArm, SyntheticFrameSource
    from hardware.interfaces import VirtualClock

    clock, policy = VirtualClock(), load_policy(checkpoint)
    frames = {n: SyntheticFrameSource(n, (24, 32), clock, background=n in ("left", "right"))
              for n in ("third_view", "wrist", "left", "right")}
    setup = Setup(FakeArm((0.4, 0.0, 0.2, 0.0), clock), None, {n: frames[n] for n in ("third_view", "wrist")},
                  {n: frames[n] for n in ("left", "right")}, SafetyLimits(**FAKE_WORKSPACE), LoopTiming(inference="sync"), clock)
    stats = deploy(setup, policy, max_steps=3)
    assert stats.steps == 3 and len(stats.inference_s) == 3 and set(stats.inference_s) == {0.0}  # clock seconds
    timed = WallTimed(policy)
    assert timed.config is policy.config and timed.wall_s == []


def test_deploy_cli_reports_a_corrupted_checkpoint(checkpoint, capsys):
    from controltac_il.app import deploy_cli as deploy_policy

    (checkpoint / "model.safetensors").write_bytes(b"garbage")
    assert deploy_policy.main(["--robot", "sim", "--checkpoint", str(checkpoint), "--episodes", "1"]) == 2
    assert "corrupted" in capsys.readouterr().err
    assert deploy_policy.main(["--robot", "xarm", "--checkpoint", str(checkpoint)]) == 2  # no --config
    assert "--config" in capsys.readouterr().err


def test_deploy_cli_runs_the_touch_critical_scene(checkpoint, tmp_path):
    import json

    from controltac_il.app import deploy_cli as deploy_policy

    out = tmp_path / "result.json"
    assert deploy_policy.main(["--robot", "sim", "--scene", "touch_critical", "--checkpoint", str(checkpoint),
                               "--episodes", "1", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["grip_force_range_n"] == [4.0, 7.0] and result["episodes"] == 1
    assert result["outcomes"][0]["steps"] == 60  # an untrained policy never inserts: the variant's limit


@pytest.mark.parametrize("flags, named", [
    (["--episodes", "0"], "--episodes"), (["--episodes", "-3"], "--episodes"), (["--max-steps", "0"], "--max-steps"),
    (["--threads", "0"], "--threads"), (["--grip-force", "9", "3"], "--grip-force"),
    (["--grip-force", "-1", "3"], "--grip-force"), (["--seed", "-1"], "--seed"),
    (["--config", "setup.yaml"], "--config setup.yaml: a robot set-up, used only with --robot xarm|ur"),
    (["--max-steps", "5"], "--max-steps 5: a robot run's length; a simulated episode ends at its scene's"),
    (["--out", "/proc/controltac-result.json"], "cannot write the result there (no file can be made in /proc"),
])
def test_deploy_cli_validation_errors_are_one_line_naming_the_flag(checkpoint, capsys, flags, named):
    from controltac_il.app import deploy_cli as deploy_policy

    assert deploy_policy.main(["--robot", "sim", "--checkpoint", str(checkpoint), *flags]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and named in err[0], err


@pytest.mark.parametrize("flag", [["--episodes", "5"], ["--seed", "3"], ["--scene", "touch_critical"],
                                  ["--grip-force", "3", "5"]])
def test_a_simulation_setting_given_for_a_robot_is_refused_not_ignored(checkpoint, capsys, flag):
    from controltac_il.app import deploy_cli as deploy_policy

    setup = Path(__file__).resolve().parents[1] / "hardware" / "configs" / "xarm7_gelsight.yaml"
    assert deploy_policy.main(["--robot", "xarm", "--config", str(setup), "--checkpoint", str(checkpoint), *flag]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{flag[0]}: a simulated episode's setting, used only with --robot sim" in err[0], err


def test_deploy_cli_never_writes_its_result_over_an_existing_file(checkpoint, tmp_path, capsys):
    from controltac_il.app import deploy_cli as deploy_policy

    notes = tmp_path / "notes.txt"
    notes.write_text("the user's own")
    assert deploy_policy.main(["--robot", "sim", "--checkpoint", str(checkpoint), "--out", str(notes)]) == 2
    assert "exists: a result never replaces a file" in capsys.readouterr().err and notes.read_text() == "the user's own"


def _raising(monkeypatch, bad: set[int]):
    """Every ACTPolicy loaded from now on raises in the episodes ``bad`` (counted by SimRobot openings)."""
    import envs.sim_robot as sim_robot

    state = {"episode": -1}
    enter = sim_robot.SimRobot.__enter__

    def counting_enter(self):
        state["episode"] += 1
        return enter(self)

    def call(self, observation, _orig=ACTPolicy.__call__):
        if state["episode"] in bad:
            raise RuntimeError(f"boom in episode {state['episode']}\nsecond line")
        return _orig(self, observation)

    monkeypatch.setattr(sim_robot.SimRobot, "__enter__", counting_enter)
    monkeypatch.setattr(ACTPolicy, "__call__", call)


def test_an_episode_that_raises_is_reported_never_counted_as_a_failure(checkpoint, monkeypatch):
    from controltac_il.app import EvaluationError, evaluate_in_sim

    _raising(monkeypatch, {1})
    res = evaluate_in_sim(checkpoint, episodes=2, seed=100, progress=False, on_error="report",
                          env_overrides={"max_steps": 3})  # the episode that runs: short
    assert res["errors"] == [{"seed": 101, "error": "PolicyError: policy raised RuntimeError: boom in episode 1 second line"}]
    assert [o["success"] for o in res["outcomes"]][1] is None and res["episodes"] == 2
    assert res["successes"] == sum(o["success"] is True for o in res["outcomes"])
    _raising(monkeypatch, {0, 1})
    with pytest.raises(EvaluationError, match=r"^cell x: 2 of 2 episodes raised and were not counted \(first: seed 100: "
                                              r"PolicyError: policy raised RuntimeError: boom in episode 0 second line\)$") as err:
        evaluate_in_sim(checkpoint, episodes=2, seed=100, progress=False, label="cell x")
    assert [e["seed"] for e in err.value.result["errors"]] == [100, 101]
    import pickle

    again = pickle.loads(pickle.dumps(err.value))  # crosses the verdict's process pool intact
    assert str(again) == str(err.value) and again.result == err.value.result


def test_deploy_cli_exits_1_on_an_episode_that_raised_and_writes_every_error(checkpoint, tmp_path, monkeypatch, capsys):
    import json

    from controltac_il.app import deploy_cli as deploy_policy

    _raising(monkeypatch, {0})
    out = tmp_path / "result.json"
    assert deploy_policy.main(["--robot", "sim", "--checkpoint", str(checkpoint), "--episodes", "2", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()[-1]  # after the progress bar: one line
    assert err.startswith("deploy_policy.py: error: evaluation: 1 of 2 episodes raised") and "seed 100000" in err
    assert json.loads(out.read_text())["errors"][0]["error"].startswith("PolicyError: policy raised RuntimeError: boom")
