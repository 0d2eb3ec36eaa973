"""What the imitation-learning experiments (``benchmarks.touch_il``, ``benchmarks.verdict``,
``benchmarks.act``) need of the scene and the policy, so that they never reach below the wiring: the
touch-critical scene, a cpu-preset ACT trained on a folder of demos under one augmentation stage (resumable,
with snapshots), and the checkpoint of a run at a step."""

from __future__ import annotations

import time
from pathlib import Path

from envs.config import EVAL_SEED, PegInHoleConfig
from policies.act import ACTConfig
from policies.act.data import load_training_data
from policies.act.training import ACTTrainConfig, augment_change, snapshot_path, train_on_folder

__all__ = ["EVAL_SEED", "augment_change", "policy_meta", "snapshot_path", "touch_scene", "train_policy",
           "training_split"]


def touch_scene(**overrides) -> PegInHoleConfig:
    """``PegInHoleConfig.touch_critical(**overrides)``: the scene only touch can solve."""
    return PegInHoleConfig.touch_critical(**overrides)


def training_split(demos_dir: str | Path):
    """The training split (split seed 0, 10 % of the episodes held out) a cpu-preset policy trains on: what a
    ForceAugment cache is built over before workers read it."""
    return load_training_data(demos_dir, ACTConfig.from_preset("cpu").chunk_size, 0.1, 0).train


def policy_meta(run: str | Path) -> dict:
    """The meta of a training run's ``run/last`` checkpoint ({} when there is no readable one yet)."""
    import json

    try:
        return json.loads((Path(run) / "last" / "config.json").read_text())["meta"]
    except (OSError, KeyError, json.JSONDecodeError):
        return {}


def train_policy(demos_dir: str | Path, run: str | Path, *, steps: int, batch_size: int, seed: int = 0,
                 augment=None, vision_only: bool = False, snapshot_every: int = 0, val_every: int = 500) -> float:
    """Train a cpu-preset ACT on ``demos_dir`` into ``run`` up to ``steps`` (continuing ``run/last`` when there);
    returns the seconds spent now (0.0 when it was already trained). ``augment``: an AugmentStage (``controltac_il.
    datasets.stage``); vision_only: no tactile streams. Demos split with seed 0 whatever ``seed``, so that training
    seeds vary on one split (and one ForceAugment cache)."""
    run = Path(run)
    if policy_meta(run).get("step", 0) >= steps:
        return 0.0
    t = time.perf_counter()
    train_on_folder(demos_dir, run, preset="cpu", augment=augment, tactile_sensors=() if vision_only else None,
                    train_config=ACTTrainConfig(steps=steps, batch_size=batch_size, val_every=min(val_every, steps),
                                             snapshot_every=snapshot_every, seed=seed),
                    split_seed=0, resume=(run / "last").is_dir(), progress=False)
    return round(time.perf_counter() - t, 1)
