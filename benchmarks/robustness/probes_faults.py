"""Runtime faults on every CLI a user runs: a missing or corrupt file, a robot that does not answer, a checkpoint
that does not fit, Ctrl-C, an output it cannot write. Each must print one line on stderr and exit non-zero (2 bad
input or files, 1 a device or a NaN loss, 130 Ctrl-C); the rows record the exit code and whether it was one line.

An output "under a regular file" (``FILE/out``) cannot be written by anyone, root included (the probes run as
whoever runs the benchmark, so a read-only folder would not do)."""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks.robustness.harness import (
    demo_episodes, judge_fault, probe, run_cli, run_cli_interrupted, setup_yaml, tiny_checkpoint,
)
from benchmarks.robustness.probes_models import _sensor_dataset

BAR = r"\d+%\||it/s\]|s/it\]"  # a tqdm progress bar has shown: the command is at work


def fault(surface: str, name: str):
    return probe(surface, name, fault=True)


def _under_a_file(tmp: Path) -> Path:
    (tmp / "a_file").write_text("the user's")
    return tmp / "a_file" / "out"


# -- train_act.py --------------------------------------------------------------------------------------------

TRAIN = ["train_act.py", "--batch-size", "2", "--val-every", "2", "--chunk-size", "6"]


def _train(tmp: Path, *extra: str, steps: str = "2"):
    data = demo_episodes(tmp / "demos") if not (tmp / "demos").is_dir() else tmp / "demos"
    return run_cli([*TRAIN, "--steps", steps, "--dataset", str(data), *extra], cache=tmp / "cache")


@fault("train_act.py", "--out under a regular file (cannot be written)")
def _(tmp):
    return judge_fault(_train(tmp, "--out", str(_under_a_file(tmp))), "a_file", code=2)


@fault("train_act.py", "--dataset folder holding no episode files")
def _(tmp):
    (tmp / "empty").mkdir()
    res = run_cli([*TRAIN, "--steps", "2", "--dataset", str(tmp / "empty"), "--out", str(tmp / "run")],
                  cache=tmp / "cache")
    return judge_fault(res, "empty", code=2)


@fault("train_act.py", "--resume from a corrupt last/ checkpoint")
def _(tmp):
    if _train(tmp, "--out", str(tmp / "run")).returncode != 0:
        return judge_fault(_train(tmp, "--out", str(tmp / "run2")))
    (tmp / "run" / "last" / "model.safetensors").write_bytes(b"garbage")
    return judge_fault(_train(tmp, "--out", str(tmp / "run"), "--resume", steps="4"), "model.safetensors", code=2)


@fault("train_act.py", "--augment force with a --generator that does not exist")
def _(tmp):
    return judge_fault(_train(tmp, "--out", str(tmp / "run"), "--augment", "force", "--copies", "1", "--generator",
                              str(tmp / "nowhere")), "nowhere", code=2)


@fault("train_act.py", "Ctrl-C during training")
def _(tmp):
    data = demo_episodes(tmp / "demos")
    res = run_cli_interrupted([*TRAIN, "--steps", "100000", "--dataset", str(data), "--out", str(tmp / "run")],
                              wait_for=r"/100000 \[", after_s=3, cache=tmp / "cache")
    return judge_fault(res, code=130)


# -- deploy_policy.py ----------------------------------------------------------------------------------------

def _robot_setup(tmp: Path, robot: str = "xarm", **control) -> Path:
    """A valid setup for the tiny checkpoint's cameras and sensors, the controller at 127.0.0.1 (nothing listens)."""
    def edit(c):
        c["cameras"]["wrist"] = {"device": "/dev/video2"}
        c["tactile"]["right"] = {"device": "GelSight Mini"}
        c["control"].update(control)
        if robot == "ur":
            c["robot"] = {"type": "ur", "ip": "127.0.0.1", "model": "ur5"}
            c["gripper"] = {"type": "none"}
    return setup_yaml(tmp, edit)


def _deploy_robot(tmp: Path, setup: Path, robot: str = "xarm", ckpt: Path | None = None):
    ckpt = ckpt or tiny_checkpoint(tmp / "ckpt")
    return run_cli(["deploy_policy.py", "--robot", robot, "--checkpoint", str(ckpt), "--config", str(setup),
                    "--max-steps", "5"], cache=tmp / "cache", timeout=120)


@fault("deploy_policy.py", "--robot xarm whose controller does not answer (127.0.0.1)")
def _(tmp):
    return judge_fault(_deploy_robot(tmp, _robot_setup(tmp)), "127.0.0.1", "setup.yaml", code=1)


@fault("deploy_policy.py", "--robot ur whose controller does not answer (127.0.0.1)")
def _(tmp):
    return judge_fault(_deploy_robot(tmp, _robot_setup(tmp, "ur"), "ur"), "127.0.0.1", "setup.yaml", code=1)


@fault("deploy_policy.py", "--config that does not exist")
def _(tmp):
    return judge_fault(_deploy_robot(tmp, tmp / "nowhere.yaml"), "nowhere.yaml", code=2)


@fault("deploy_policy.py", "a checkpoint for a camera the setup lacks")
def _(tmp):
    setup = setup_yaml(tmp, lambda c: c["tactile"].update(right={"device": "GelSight Mini"}))
    return judge_fault(_deploy_robot(tmp, setup), "wrist", code=2)


@fault("deploy_policy.py", "a checkpoint whose config.json does not fit its weights")
def _(tmp):
    ckpt = tiny_checkpoint(tmp / "ckpt")
    cfg = json.loads((ckpt / "config.json").read_text())
    cfg["act"]["dim_feedforward"] = 2 * cfg["act"]["dim_feedforward"]
    (ckpt / "config.json").write_text(json.dumps(cfg))
    return judge_fault(_deploy_robot(tmp, _robot_setup(tmp), ckpt=ckpt), "ckpt", code=2)


@fault("deploy_policy.py", "a setup whose inference deadline is longer than the policy's chunk")
def _(tmp):
    # the tiny checkpoint's chunk is 6 steps = 0.6 s at 10 Hz: a 1 s deadline could never fire
    return judge_fault(_deploy_robot(tmp, _robot_setup(tmp, inference_deadline_s=1.0)), "inference_deadline_s",
                       "chunk_size", code=2)


@fault("deploy_policy.py", "a setup file that states the chunk size (the policy's)")
def _(tmp):
    return judge_fault(_deploy_robot(tmp, _robot_setup(tmp, chunk_size=20)), "chunk_size", code=2)


@fault("deploy_policy.py", "--out in a folder that does not exist")
def _(tmp):
    res = run_cli(["deploy_policy.py", "--robot", "sim", "--checkpoint", str(tiny_checkpoint(tmp / "ckpt")),
                   "--episodes", "1", "--out", str(tmp / "nowhere" / "result.json")], cache=tmp / "cache")
    return judge_fault(res, "--out", code=2)


@fault("deploy_policy.py", "Ctrl-C during a simulated evaluation")
def _(tmp):
    res = run_cli_interrupted(["deploy_policy.py", "--robot", "sim", "--checkpoint", str(tiny_checkpoint(tmp / "ckpt")),
                               "--episodes", "50"], wait_for=BAR, after_s=3, cache=tmp / "cache")
    return judge_fault(res, code=130)


# -- python -m controltac_il ---------------------------------------------------------------------------------

@fault("python -m controltac_il", "--out under a regular file (cannot be written)")
def _(tmp):
    res = run_cli(["-m", "controltac_il", "--out", str(_under_a_file(tmp)), "--sensor-only"], cache=tmp / "cache")
    return judge_fault(res, "a_file", code=2)


@probe("python -m controltac_il", "--demos 0")
def _(tmp):
    res = run_cli(["-m", "controltac_il", "--out", str(tmp / "out"), "--demos", "0"], cache=tmp / "cache")
    return judge_fault(res, "--demos", code=2)


@fault("python -m controltac_il", "Ctrl-C while collecting the demos")
def _(tmp):
    res = run_cli_interrupted(["-m", "controltac_il", "--out", str(tmp / "out"), "--demos", "4", "--steps", "4",
                               "--eval-episodes", "1"], wait_for=r"\[sensor\]", after_s=4, cache=tmp / "cache")
    return judge_fault(res, code=130)


# -- python -m controltac_il.augment -------------------------------------------------------------------------

def _augment(tmp: Path, *extra: str, data: Path | None = None, out: Path | None = None):
    data = data or demo_episodes(tmp / "demos", n=2)
    return run_cli(["-m", "controltac_il.augment", "--dataset", str(data), "--out", str(out or tmp / "aug"),
                    "--copies", "1", *extra], cache=tmp / "cache")


@fault("augment", "a corrupt episode file")
def _(tmp):
    data = demo_episodes(tmp / "demos", n=2)
    (data / "episode_1.hdf5").write_bytes(b"not an hdf5 file")
    return judge_fault(_augment(tmp, data=data), "episode_1.hdf5", code=2)


@fault("augment", "--out under a regular file (cannot be written)")
def _(tmp):
    return judge_fault(_augment(tmp, out=_under_a_file(tmp)), "a_file", code=2)


@fault("augment", "--generator that does not exist")
def _(tmp):
    return judge_fault(_augment(tmp, "--generator", str(tmp / "nowhere")), "nowhere", code=2)


@fault("augment", "Ctrl-C while building the cache")
def _(tmp):
    data = demo_episodes(tmp / "demos", n=4, frames=60)
    res = run_cli_interrupted(["-m", "controltac_il.augment", "--dataset", str(data), "--out", str(tmp / "aug"),
                               "--copies", "3"], wait_for=BAR, after_s=2, cache=tmp / "cache")
    return judge_fault(res, code=130)


# -- python -m controltac_il.generator.training stage1 / stage2 ---------------------------------------------

def _corrupt_manifest(tmp: Path) -> Path:
    data = _sensor_dataset(tmp)
    (data / "manifest.csv").write_text("this is not\x00 a manifest\n")
    return data


@fault("generator.training stage1", "a corrupt manifest.csv in --data")
def _(tmp):
    res = run_cli(["-m", "controltac_il.generator.training", "stage1", "--data", str(_corrupt_manifest(tmp)), "--out",
                   str(tmp / "g"), "--ae-steps", "1", "--dit-steps", "1"])
    return judge_fault(res, "manifest", code=2)


@fault("generator.training stage1", "--out under a regular file (cannot be written)")
def _(tmp):
    res = run_cli(["-m", "controltac_il.generator.training", "stage1", "--data", str(_sensor_dataset(tmp)), "--out",
                   str(_under_a_file(tmp)), "--ae-steps", "1", "--dit-steps", "1"])
    return judge_fault(res, "a_file", code=2)


@fault("generator.training stage1", "Ctrl-C during training")
def _(tmp):
    res = run_cli_interrupted(["-m", "controltac_il.generator.training", "stage1", "--data", str(_sensor_dataset(tmp)),
                               "--out", str(tmp / "g"), "--ae-steps", "100000", "--dit-steps", "1", "--ae-batch", "2"],
                              wait_for=BAR, after_s=3)
    return judge_fault(res, code=130)


POSE = ["-m", "controltac_il.generator.training", "stage2", "--scenes", "1", "--poses", "2", "--forces", "2", "--size",
        "60", "80", "--batch", "2"]


@fault("generator.training stage2", "--base checkpoint that does not exist")
def _(tmp):
    res = run_cli([*POSE, "--out", str(tmp / "p"), "--steps", "1", "--base", str(tmp / "nowhere")])
    return judge_fault(res, "nowhere", code=2)


@fault("generator.training stage2", "--out under a regular file (cannot be written)")
def _(tmp):
    return judge_fault(run_cli([*POSE, "--out", str(_under_a_file(tmp)), "--steps", "1"]), "a_file", code=2)


@fault("generator.training stage2", "Ctrl-C during training")
def _(tmp):
    res = run_cli_interrupted([*POSE, "--out", str(tmp / "p"), "--steps", "100000"], wait_for=BAR, after_s=3)
    return judge_fault(res, code=130)


# -- python -m controltac_il.estimators.train ----------------------------------------------------------------

@fault("estimators.train", "a corrupt manifest.csv in --data")
def _(tmp):
    res = run_cli(["-m", "controltac_il.estimators.train", "--data", str(_corrupt_manifest(tmp)), "--out",
                   str(tmp / "e"), "--steps", "1"])
    return judge_fault(res, "manifest", code=2)


@fault("estimators.train", "--out under a regular file (cannot be written)")
def _(tmp):
    res = run_cli(["-m", "controltac_il.estimators.train", "--data", str(_sensor_dataset(tmp)), "--out",
                   str(_under_a_file(tmp)), "--steps", "1"])
    return judge_fault(res, "a_file", code=2)


@fault("estimators.train", "Ctrl-C during training")
def _(tmp):
    res = run_cli_interrupted(["-m", "controltac_il.estimators.train", "--data", str(_sensor_dataset(tmp)), "--out",
                               str(tmp / "e"), "--steps", "100000", "--batch-size", "2"], wait_for=BAR, after_s=3)
    return judge_fault(res, code=130)


# -- python -m controltac_il.tactile.dataset / envs.collect --------------------------------------------------

DATASET = ["-m", "controltac_il.tactile.dataset", "--objects", "cross", "--poses-per-object", "2",
           "--forces-per-pose", "2", "--size", "60", "80"]


@fault("tactile.dataset", "--out under a regular file (cannot be written)")
def _(tmp):
    return judge_fault(run_cli([*DATASET, "--out", str(_under_a_file(tmp))]), "a_file", code=2)


@fault("tactile.dataset", "Ctrl-C while rendering")
def _(tmp):
    res = run_cli_interrupted(["-m", "controltac_il.tactile.dataset", "--out", str(tmp / "d"), "--procedural", "200",
                               "--poses-per-object", "4", "--forces-per-pose", "4"], wait_for=BAR, after_s=3)
    return judge_fault(res, code=130)


@fault("envs.collect", "--out under a regular file (cannot be written)")
def _(tmp):
    res = run_cli(["-m", "envs.collect", "--episodes", "1", "--out", str(_under_a_file(tmp))], cache=tmp / "cache")
    return judge_fault(res, "a_file", code=2)


@fault("envs.collect", "Ctrl-C while collecting")
def _(tmp):
    res = run_cli_interrupted(["-m", "envs.collect", "--episodes", "50", "--out", str(tmp / "d")], wait_for=BAR,
                              after_s=4, cache=tmp / "cache")
    return judge_fault(res, code=130)


# -- python -m controltac_il.sign ----------------------------------------------------------------------------

@fault("controltac_il.sign", "a folder that does not exist")
def _(tmp):
    return judge_fault(run_cli(["-m", "controltac_il.sign", str(tmp / "nowhere")]), "nowhere", code=2)


@fault("controltac_il.sign", "a corrupt model_card.json")
def _(tmp):
    ckpt = tiny_checkpoint(tmp / "ckpt")
    (ckpt / "model_card.json").write_text("{not json")
    return judge_fault(run_cli(["-m", "controltac_il.sign", str(ckpt)]), "model_card.json", code=2)


@fault("controltac_il.sign", "a model card that cannot be written (model_card.json is a folder)")
def _(tmp):
    ckpt = tiny_checkpoint(tmp / "ckpt")
    (ckpt / "model_card.json").unlink()
    (ckpt / "model_card.json").mkdir()
    return judge_fault(run_cli(["-m", "controltac_il.sign", str(ckpt)]), "model_card.json", code=2)
