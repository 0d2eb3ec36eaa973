"""Probes of train_act.py, EpisodeDataset and deploy_policy.py: user files, bad data, bad flags, garbage weights."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.robustness.harness import (
    HANDLED, LOSS, REPO, SILENT, demo_episodes, edit_episode, judge_call, judge_cli, lost, outcome, probe,
    run_cli, snapshot, tiny_checkpoint,
)

TRAIN = ["train_act.py", "--steps", "2", "--batch-size", "2", "--val-every", "2", "--chunk-size", "6"]


def _train(tmp: Path, *extra: str, dataset: Path | None = None) -> subprocess.CompletedProcess:
    data = dataset or demo_episodes(tmp / "demos")
    return run_cli([*TRAIN, "--dataset", str(data), *extra], cache=tmp / "cache")


@probe("train_act.py", "--out onto a finished run without --resume")
def _(tmp):
    out = tmp / "run"
    assert _train(tmp, "--out", str(out)).returncode == 0
    before = snapshot(out)
    res = _train(tmp, "--out", str(out))
    if lost(before, out):
        return LOSS, f"exit {res.returncode}; replaced {', '.join(lost(before, out)[:3])}"
    return judge_cli(res, "--resume")


@probe("train_act.py", "--out onto a folder of the user's own with best/ and last/")
def _(tmp):
    out = tmp / "mine"
    for sub in ("best", "last"):
        (out / sub).mkdir(parents=True)
        (out / sub / "notes.txt").write_text("my notes")
    (out / "train_log.json").write_text('{"mine": true}')
    before = snapshot(out)
    res = _train(tmp, "--out", str(out))
    if lost(before, out):
        return LOSS, f"exit {res.returncode}; changed or removed {', '.join(lost(before, out))}"
    return judge_cli(res, str(out))


@probe("train_act.py", "--chunk-size larger than every episode")
def _(tmp):
    return judge_cli(_train(tmp, "--out", str(tmp / "run"), "--chunk-size", "500"), "--chunk-size|chunk_size")


@probe("train_act.py", "--steps 0")
def _(tmp):
    return judge_cli(_train(tmp, "--out", str(tmp / "run"), "--steps", "0"), "--steps|steps")


@probe("train_act.py", "--batch-size -4")
def _(tmp):
    return judge_cli(_train(tmp, "--out", str(tmp / "run"), "--batch-size", "-4"), "--batch-size|batch_size")


@probe("train_act.py", "--val-fraction 1.5")
def _(tmp):
    return judge_cli(_train(tmp, "--out", str(tmp / "run"), "--val-fraction", "1.5"), "--val-fraction|val_fraction")


@probe("train_act.py", "--augment force --copies 12")
def _(tmp):
    return judge_cli(_train(tmp, "--out", str(tmp / "run"), "--augment", "force", "--copies", "12"), "copies")


@probe("train_act.py", "--dataset that does not exist")
def _(tmp):
    return judge_cli(_train(tmp, "--out", str(tmp / "run"), dataset=tmp / "nowhere"), "nowhere")


@probe("train_act.py", "a corrupt episode file")
def _(tmp):
    data = demo_episodes(tmp / "demos")
    (data / "episode_2.hdf5").write_bytes(b"not an hdf5 file")
    return judge_cli(_train(tmp, "--out", str(tmp / "run"), dataset=data), "episode_2.hdf5")


@probe("train_act.py", "an episode whose actions are shorter than its qpos")
def _(tmp):
    data = demo_episodes(tmp / "demos")
    edit_episode(data / "episode_1.hdf5", "action", np.zeros((20, 5), np.float32))
    return judge_cli(_train(tmp, "--out", str(tmp / "run"), dataset=data), "episode_1.hdf5", "action")


@probe("train_act.py", "actions containing NaN")
def _(tmp):
    data = demo_episodes(tmp / "demos")
    bad = np.zeros((30, 5), np.float32)
    bad[5] = np.nan
    edit_episode(data / "episode_0.hdf5", "action", bad)
    return judge_cli(_train(tmp, "--out", str(tmp / "run"), dataset=data), "episode_0.hdf5", "nan")


@probe("train_act.py", "--resume onto another dataset of the same layout")
def _(tmp):
    out = tmp / "run"
    assert _train(tmp, "--out", str(out)).returncode == 0
    other = demo_episodes(tmp / "other", seed=5)
    edit_episode(other / "episode_0.hdf5", "action", np.full((30, 5), 3.0, np.float32))
    before = snapshot(out)
    res = _train(tmp, "--out", str(out), "--resume", "--steps", "4", dataset=other)
    if res.returncode == 0:
        return SILENT, "resumed on another dataset" + ("; stats.json replaced" if lost(before, out) else "")
    return judge_cli(res, "dataset")


@probe("train_act.py", "Ctrl-C during training keeps the steps done")
def _(tmp):
    import time

    data = demo_episodes(tmp / "demos", frames=60)
    out, log = tmp / "run", tmp / "stderr.txt"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(REPO), "CONTROLTAC_CACHE": str(tmp / "cache")}
    with open(log, "w") as err:
        proc = subprocess.Popen([sys.executable, "train_act.py", "--dataset", str(data), "--out", str(out), "--steps",
                                 "100000", "--batch-size", "2", "--chunk-size", "6", "--val-every", "100000"],
                                cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=err,
                                # a background shell starts us with SIGINT ignored; Ctrl-C must reach the child
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        deadline = time.monotonic() + 240  # wait until the progress bar shows steps taken, then a few more
        while time.monotonic() < deadline and proc.poll() is None and "/100000 [" not in log.read_text():
            time.sleep(0.5)
        time.sleep(5.0)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
    cfg = out / "last" / "config.json"
    step = json.loads(cfg.read_text()).get("meta", {}).get("step", 0) if cfg.is_file() else 0
    reported = outcome(subprocess.CompletedProcess([], proc.returncode, "", log.read_text()))
    if step > 0:
        return HANDLED, f"exit {proc.returncode}; last/ holds step {step}", reported
    return SILENT, f"exit {proc.returncode}; nothing saved ({'no last/' if not cfg.is_file() else 'step 0'})", reported


@probe("EpisodeDataset", "stats_path pointing at a file of the user's")
def _(tmp):
    from controltac_il.datasets import EpisodeDataset

    data = demo_episodes(tmp / "demos")
    mine = tmp / "notes.json"
    mine.write_text('{"my": "notes"}')
    verdict = judge_call(lambda: EpisodeDataset(data, chunk_size=6, stats_path=mine), "notes.json")
    if mine.read_text() != '{"my": "notes"}':
        return LOSS, "overwrote the user's file"
    return (HANDLED, "left alone") if verdict[0] == SILENT else verdict


@probe("EpisodeDataset", "a sensor missing from episode 0 only")
def _(tmp):
    from controltac_il.datasets import EpisodeDataset

    data = demo_episodes(tmp / "demos", drop_tactile_in=(0,))
    ds_holder = {}

    def make():
        ds_holder["ds"] = EpisodeDataset(data, chunk_size=6, stats_path=tmp / "stats.json")

    verdict = judge_call(make, "right")
    if verdict[0] == SILENT and "right" not in ds_holder["ds"].tactile_sensors:
        return SILENT, "the 'right' sensor of episodes 1-3 was dropped for all episodes"
    return verdict


@probe("EpisodeDataset", "tactile frames fewer than actions")
def _(tmp):
    from controltac_il.datasets import EpisodeDataset

    data = demo_episodes(tmp / "demos")
    edit_episode(data / "episode_3.hdf5", "observations/tactile/left", np.zeros((10, 24, 32, 3), np.uint8))

    def read_all():
        ds = EpisodeDataset(data, chunk_size=6, stats_path=tmp / "stats.json")
        for i in range(len(ds)):
            ds[i]

    return judge_call(read_all, "episode_3.hdf5")


@probe("EpisodeDataset", "an episode without /action")
def _(tmp):
    from controltac_il.datasets import EpisodeDataset

    data = demo_episodes(tmp / "demos")
    edit_episode(data / "episode_2.hdf5", "action", None)
    return judge_call(lambda: EpisodeDataset(data, chunk_size=6, stats_path=tmp / "s.json"), "episode_2.hdf5",
                      "action")


def _scaled_forces(data: Path, scale: float) -> Path:
    """The episodes of ``data`` with every force label times ``scale``, edited in place past the writer (which
    refuses labels in mN or pulling): what a file from another tool may hold."""
    import h5py

    for path in sorted(data.glob("episode_*.hdf5")):
        with h5py.File(path, "r") as f:
            forces = {k: f[f"observations/force/{k}"][()] for k in f["observations/force"]}
        for k, values in forces.items():
            edit_episode(path, f"observations/force/{k}", values * scale)
    return data


@probe("EpisodeDataset", "force labels in mN")
def _(tmp):
    from controltac_il.datasets import EpisodeDataset

    data = _scaled_forces(demo_episodes(tmp / "demos"), 1000.0)
    return judge_call(lambda: EpisodeDataset(data, chunk_size=6, stats_path=tmp / "s.json"), "force")


@probe("EpisodeDataset", "negative pressing force labels")
def _(tmp):
    from controltac_il.datasets import EpisodeDataset

    data = _scaled_forces(demo_episodes(tmp / "demos"), -1.0)
    return judge_call(lambda: EpisodeDataset(data, chunk_size=6, stats_path=tmp / "s.json"), "force")


@probe("EpisodeDataset", "NaN force labels")
def _(tmp):
    from controltac_il.datasets import EpisodeDataset

    data = demo_episodes(tmp / "demos")
    bad = np.zeros((30, 3), np.float32)
    bad[20:, 2] = np.nan
    edit_episode(data / "episode_1.hdf5", "observations/force/left", bad)
    return judge_call(lambda: EpisodeDataset(data, chunk_size=6, stats_path=tmp / "s.json"), "episode_1.hdf5")


def _ckpt_with(tmp: Path, change) -> Path:
    from safetensors.numpy import load_file, save_file

    ckpt = tiny_checkpoint(tmp / "ckpt")
    weights = ckpt / "model.safetensors"
    tensors = load_file(weights)
    change(tensors)
    save_file(tensors, weights)
    return ckpt


def _deploy(ckpt: Path, *extra: str, tmp: Path) -> subprocess.CompletedProcess:
    return run_cli(["deploy_policy.py", "--robot", "sim", "--checkpoint", str(ckpt), "--episodes", "1", *extra],
                   cache=tmp / "cache")


@probe("deploy_policy.py", "a checkpoint with NaN weights")
def _(tmp):
    def poison(t):
        k = next(k for k, v in t.items() if v.dtype.kind == "f" and v.size > 1)
        t[k] = t[k].copy()
        t[k].flat[0] = np.nan
    return judge_cli(_deploy(_ckpt_with(tmp, poison), tmp=tmp), "model.safetensors")


@probe("deploy_policy.py", "weights changed after the checkpoint was written")
def _(tmp):
    def tweak(t):
        k = next(k for k, v in t.items() if v.dtype.kind == "f" and v.size > 1)
        t[k] = t[k] * 1.5
    return judge_cli(_deploy(_ckpt_with(tmp, tweak), tmp=tmp), "model.safetensors")


@probe("deploy_policy.py", "--checkpoint that does not exist")
def _(tmp):
    return judge_cli(_deploy(tmp / "nowhere", tmp=tmp), "nowhere")


@probe("deploy_policy.py", "--episodes 0")
def _(tmp):
    return judge_cli(_deploy(tiny_checkpoint(tmp / "ckpt"), "--episodes", "0", tmp=tmp), "--episodes")


@probe("deploy_policy.py", "--grip-force 9 3 (low above high)")
def _(tmp):
    return judge_cli(_deploy(tiny_checkpoint(tmp / "ckpt"), "--grip-force", "9", "3", tmp=tmp), "grip")


@probe("deploy_policy.py", "--robot xarm with a setup whose ip is not an address")
def _(tmp):
    from benchmarks.robustness.harness import setup_yaml

    def edit(c):
        c["robot"]["ip"] = "not an ip"
        c["cameras"]["wrist"] = {"device": "/dev/video2"}
        c["tactile"]["right"] = {"device": "GelSight Mini"}

    cfg = setup_yaml(tmp, edit)
    res = run_cli(["deploy_policy.py", "--robot", "xarm", "--checkpoint", str(tiny_checkpoint(tmp / "ckpt")),
                   "--config", str(cfg)], cache=tmp / "cache", timeout=60)
    return judge_cli(res, "ip")
