"""ACT training loop: AdamW, periodic validation, atomic checkpoints, resume, torchrun data parallelism.

Works on any map-style dataset whose items follow the EpisodeDataset contract (LeRobot-style keys,
see ``ACTConfig.input_keys`` plus ``action`` / ``action_is_pad``). Under ``torchrun`` each process
trains on its shard (``StepBatches``) and gradients are averaged (DDP; gloo on CPU, nccl on CUDA);
rank 0 validates, logs and writes checkpoints.

Output folder::

    OUT/last/        newest checkpoint + optimizer state (what --resume continues from)
    OUT/best/        checkpoint with the lowest validation L1 (z = 0, as deployed)
    OUT/train_log.json   losses and validation curve up to the step last/ holds

Only the entries above (and ``snapshots/``) are written, each where it is new or this tool's own: a previous run is
refused unless resumed (``resume``) or replaced (``overwrite``: removes only what this tool wrote); a file of the
user's at one of those names is refused, and files beside them are left alone. A NaN / inf loss stops the run (``NonFiniteLoss``) with ``last/`` left at the last
good step; Ctrl-C saves the current step to ``last/`` before stopping (``TrainingInterrupted``).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict
from pathlib import Path
from typing import Annotated

import numpy as np
import torch
import torch.distributed as dist
from pydantic import Field
from pydantic.dataclasses import dataclass
from torch.utils.data import DataLoader, Dataset
from tqdm import tqdm

from controltac_il.config import PosInt, STRICT, one_line_errors
from controltac_il.datasets.background import image_digests
from controltac_il.io import write_json
from controltac_il.outputs import claim_output, own_checkpoint, own_json
from controltac_il.streams import HDF5_STATE
from controltac_il.training import (StepBatches, barrier, lr_schedule, optimise, seed_update, setup_distributed,
                                    wrap)
from policies.act.checkpoint import (BACKGROUND_FILE, FORMAT, WEIGHTS_FILE, CheckpointError, load_checkpoint,
                                     load_optimizer_state, save_checkpoint)
from policies.act.configuration_act import ACTConfig
from policies.act.modeling_act import ACT

@one_line_errors
@dataclass(config=STRICT)
class ACTTrainConfig:
    """Optimisation schedule (pydantic: validated at construction, ValueError naming the field).

    steps: optimiser steps in total, >= 1 (a resumed run continues up to this number).
    batch_size: samples per step and per process (global batch = batch_size * world size).
    val_every: run validation (and keep ``best``) every this many steps, and at the end.
    save_every: write ``last`` (with optimizer state) every this many steps, and at the end.
    warmup_steps: linear learning-rate warm-up (update i at (i + 1) / warmup_steps of the rate), then
        constant (ACT uses a constant rate); 0 = none.
    grad_clip: max gradient L2 norm (0 = no clipping).
    num_workers: DataLoader worker processes (0 = load in the training process).
    max_val_batches: cap on validation batches per evaluation (keeps validation cheap on CPU).
    snapshot_every: also keep the weights of every this many steps in ``snapshots/step_<k>/`` (0 = none), for
        choosing the number of steps afterwards by closed-loop success (``benchmarks.verdict``).
    seed: seeds the model initialisation, the sampling order (per epoch) and, per update, dropout and the CVAE
        noise: a resumed run continues bit-identically.
    """

    steps: PosInt = 2000
    batch_size: PosInt = 16
    val_every: PosInt = 250
    save_every: PosInt = 500
    warmup_steps: Annotated[int, Field(ge=0)] = 50
    grad_clip: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 10.0
    num_workers: Annotated[int, Field(ge=0)] = 0
    max_val_batches: PosInt = 20
    snapshot_every: Annotated[int, Field(ge=0)] = 0
    seed: Annotated[int, Field(ge=0)] = 0  # numpy's generators take no negative seed


def _optimizer(model: ACT) -> torch.optim.AdamW:
    cfg = model.config
    backbone, rest = [], []
    for name, p in model.named_parameters():
        (backbone if name.split(".")[0] in ("camera_backbone", "tactile_backbone") else rest).append(p)
    return torch.optim.AdamW([{"params": rest, "lr": cfg.lr}, {"params": backbone, "lr": cfg.lr_backbone}],
                             lr=cfg.lr, weight_decay=cfg.weight_decay)


@torch.no_grad()
def evaluate(model: ACT, loader: DataLoader, max_batches: int) -> dict[str, float]:
    """Mean training loss (posterior z) and masked L1 with z = 0 (normalised units) over ``loader``."""
    was_training = model.training
    model.eval()
    totals, n = {"val_loss": 0.0, "val_l1": 0.0}, 0
    for i, batch in enumerate(loader):
        if i >= max_batches:
            break
        totals["val_loss"] += float(model(batch)["loss"])
        pred = model.predict(batch)
        valid = (~batch["action_is_pad"]).unsqueeze(-1).float()
        err = ((pred - batch["action"].float()) / model.action_std).abs() * valid
        totals["val_l1"] += float(err.sum() / (valid.sum() * model.config.action_dim).clamp(min=1))
        n += 1
    model.train(was_training)
    return {k: v / max(n, 1) for k, v in totals.items()}


_CHECKPOINT_FILES = ("config.json", WEIGHTS_FILE, "stats.json", BACKGROUND_FILE, "optimizer.safetensors",
                     "optimizer.json", "model_card.json")
_own_act_checkpoint = own_checkpoint(_CHECKPOINT_FILES, lambda c: c.get("format") == FORMAT)
# what train() writes under its output folder, each with how it is recognised as this tool's own
SNAPSHOTS = "snapshots"


def snapshot_path(out_dir: str | Path, step: int) -> Path:
    """Where ``snapshot_every`` keeps the weights of ``step``: ``OUT/snapshots/step_<step, 6 digits>``."""
    return Path(out_dir) / SNAPSHOTS / f"step_{step:06d}"


def _own_snapshots(path: Path) -> str | None:
    if not path.is_dir():
        return "not a folder"
    for sub in sorted(path.iterdir()):
        why = "not a step_<k> folder" if not sub.name.startswith("step_") else _own_act_checkpoint(sub)
        if why:
            return f"{sub}: {why}"
    return None


RUN_OUTPUTS = {"last": _own_act_checkpoint, "best": _own_act_checkpoint,
               "train_log.json": own_json("step", "log", "train_config"), SNAPSHOTS: _own_snapshots}


def stats_change(before: dict, now: dict) -> str | None:
    """Which normalisation statistics differ between two runs (``"action mean, qpos std"``), or None."""
    diff = []
    for key in ("qpos", "action"):
        for m in ("mean", "std"):
            a = np.asarray(before.get(key, {}).get(m, []), dtype=np.float64).reshape(-1)
            b = np.asarray(now.get(key, {}).get(m, []), dtype=np.float64).reshape(-1)
            if a.shape != b.shape or not np.allclose(a, b, rtol=1e-5, atol=1e-6):
                diff.append(f"{key} {m}")
    return ", ".join(diff) or None


def augment_change(before: dict | None, now: dict | None) -> str | None:
    """How two runs' augmentation settings differ (``"field: old -> new, ..."``), or None when they match.

    The counts in ``summary`` (what the augmentation did) are not settings and are ignored."""
    settings = [{k: v for k, v in (d or {}).items() if k != "summary"} for d in (before, now)]
    fields = sorted(k for k in set(settings[0]) | set(settings[1]) if settings[0].get(k) != settings[1].get(k))
    return ", ".join(f"{k}: {settings[0].get(k)!r} -> {settings[1].get(k)!r}" for k in fields) or None


def _resume(out_dir: Path, model: ACT, optimizer: torch.optim.Optimizer, act_config: ACTConfig, stats: dict,
            meta: dict) -> tuple[int, float, dict, dict | None]:
    """Load ``out_dir/last`` into ``model`` and ``optimizer`` after checking it is the same run: same ACT config,
    same data (normalisation statistics, episodes) and same augmentation, else CheckpointError naming what differs.
    Returns (step, best validation L1, log, the LR schedule's saved state)."""
    if not (out_dir / "last").is_dir():
        raise CheckpointError(f"--resume: no checkpoint to continue from at {out_dir / 'last'}")
    loaded, _, last_meta = load_checkpoint(out_dir / "last")
    if loaded.config.to_dict() != act_config.to_dict():
        raise CheckpointError(f"--resume: {out_dir / 'last'} was trained with a different ACT config; "
                              f"use a new --out folder or the same --preset and options")
    change = stats_change(loaded.get_stats(), stats)
    episodes = (last_meta.get("episodes"), meta.get("episodes"))
    if change or (None not in episodes and episodes[0] != episodes[1]):
        detail = change or f"episodes {episodes[0]} -> {episodes[1]}"
        where = (f"; it was {last_meta.get('dataset')}, now {meta.get('dataset')}"
                 if last_meta.get("dataset") != meta.get("dataset") else "")
        raise CheckpointError(f"--resume: {out_dir / 'last'} was trained on another dataset (its normalisation "
                              f"statistics differ: {detail}{where}); a run never mixes two training sets: "
                              "use a new --out folder, or resume on the same dataset")
    for key in ("episode_backgrounds", "tactile_backgrounds"):  # every episode's; episode 0's (all older runs have)
        backgrounds = (last_meta.get(key), meta.get(key))
        if None not in backgrounds and backgrounds[0] != backgrounds[1]:  # e.g. another --background-image
            raise CheckpointError(f"--resume: {out_dir / 'last'} was trained on other tactile backgrounds (pixel "
                                  f"digests {backgrounds[0]} -> {backgrounds[1]}); a run never mixes two: use a new "
                                  "--out folder, or resume with the same --background-image")
    change = augment_change(last_meta.get("augment"), meta.get("augment"))
    if change:  # e.g. a retrained generator: the run would mix two training sets
        raise CheckpointError(f"--resume: {out_dir / 'last'} was trained with different augmentation ({change}); "
                              "use a new --out folder or the same --augment options and generator")
    model.load_state_dict(loaded.state_dict())
    schedule_state = load_optimizer_state(out_dir / "last", optimizer)
    best = last_meta.get("best_val_l1")  # None: no validation yet (JSON has no infinity)
    return (int(last_meta.get("step", 0)), math.inf if best is None else float(best),
            last_meta.get("log", {"train": [], "val": []}), schedule_state)


def _train_loader(train_set: Dataset, train_config: ACTTrainConfig, step: int, rank: int, world: int) -> DataLoader:
    """The shuffled training batches from update ``step`` on (``StepBatches``: epoch orders drawn from the run's
    seed, sharded per rank), the same batches at every step whether the run was resumed or not."""
    sampler = StepBatches(len(train_set), train_config.batch_size, train_config.seed, start=step, rank=rank,
                          world=world, drop_last=len(train_set) >= train_config.batch_size * world)
    return DataLoader(train_set, batch_sampler=sampler, num_workers=train_config.num_workers)


def _val_loader(val_set: Dataset | None, train_config: ACTTrainConfig) -> DataLoader | None:
    return DataLoader(val_set, batch_size=train_config.batch_size, shuffle=False) if val_set is not None and len(val_set) else None


def _validate(model: ACT, val_loader: DataLoader, train_config: ACTTrainConfig, step: int, log: dict) -> float:
    """Evaluate on the held-out episodes, log the result at ``step``; returns the validation L1 (z = 0)."""
    val = evaluate(model, val_loader, train_config.max_val_batches)
    log["val"].append({"step": step, **{k: round(v, 5) for k, v in val.items()}})
    tqdm.write(f"step {step}: val_loss {val['val_loss']:.4f}  val_l1 (z=0) {val['val_l1']:.4f}")
    return val["val_l1"]


def _start(act_config: ACTConfig, train_config: ACTTrainConfig, out_dir: Path, stats: dict, meta: dict, resume: bool
           ) -> tuple[ACT, torch.optim.Optimizer, object, int, float, dict]:
    """The model, optimizer and LR schedule of a fresh or resumed run; (…, step, best validation L1, log)."""
    torch.manual_seed(train_config.seed)
    model = ACT(act_config)
    model.set_stats(stats)
    optimizer = _optimizer(model)
    step, best, log, schedule_state = 0, math.inf, {"train": [], "val": []}, None
    if resume:
        step, best, log, schedule_state = _resume(out_dir, model, optimizer, act_config, stats, meta)
    scheduler = lr_schedule(optimizer, [act_config.lr, act_config.lr_backbone], train_config.steps,
                            train_config.warmup_steps, resume=schedule_state, step=step)
    return model, optimizer, scheduler, step, best, log


def train(act_config: ACTConfig, train_config: ACTTrainConfig, train_set: Dataset, val_set: Dataset | None,
          out_dir: str | Path, *, stats: dict, backgrounds: dict[str, np.ndarray] | None = None,
          resume: bool = False, overwrite: bool = False, meta: dict | None = None, progress: bool = True) -> dict:
    """Train ACT and write checkpoints under ``out_dir``; returns the run summary (also in train_log.json).

    stats: normalisation statistics (``{"qpos": {"mean", "std"}, "action": {...}}``) of the training data.
    backgrounds: tactile no-contact frames stored with the checkpoint for deployment.
    resume: continue from ``out_dir/last`` (its config, data statistics and augmentation must equal this run's).
    overwrite: replace a previous run in ``out_dir`` (only ``last/``, ``best/``, ``snapshots/`` and ``train_log.json``
        this tool wrote; anything else there is never touched). Without it or ``resume`` a previous run is refused.
    Raises OutputInUse (a ValueError) for an output folder it may not write, NonFiniteLoss when the loss becomes
    NaN / inf (``last/`` keeps the last good step), TrainingInterrupted on Ctrl-C after saving the current step.
    """
    out_dir = Path(out_dir)
    rank, world = setup_distributed()
    claim_output(out_dir, RUN_OUTPUTS, resume=resume, overwrite=overwrite and rank == 0, tool="train_act.py")
    if overwrite:
        barrier(world)  # rank 0 removed the replaced run
    model, optimizer, scheduler, step, best, log = _start(act_config, train_config, out_dir, stats, meta or {}, resume)
    ddp = wrap(model.train(), world)
    batches = iter(_train_loader(train_set, train_config, step, rank, world))
    val_loader = _val_loader(val_set, train_config) if rank == 0 else None
    run_meta = {**(meta or {}), "train_config": asdict(train_config), "world_size": world}
    best_l1, samples, t0 = [best], [0], time.perf_counter()

    def batch_loss(at: int) -> dict:
        seed_update(train_config.seed, at, rank)  # dropout and the CVAE's noise: a function of the step
        batch = next(batches)
        samples[0] += batch[HDF5_STATE].shape[0] * world
        return ddp(batch)

    def after_step(at: int, out: dict) -> None:
        if rank != 0:
            return
        if at % 10 == 0 or at == 1 or at == train_config.steps:
            log["train"].append({"step": at, **{k: round(float(v.detach()), 5) for k, v in out.items()}})
        if val_loader is not None and (at % train_config.val_every == 0 or at == train_config.steps):
            val_l1 = _validate(model, val_loader, train_config, at, log)
            if val_l1 < best_l1[0]:
                best_l1[0] = val_l1
                save_checkpoint(out_dir / "best", model, backgrounds=backgrounds,
                                meta={**run_meta, "step": at, "best_val_l1": val_l1})
        if train_config.snapshot_every and at % train_config.snapshot_every == 0:
            save_checkpoint(snapshot_path(out_dir, at), model, backgrounds=backgrounds, meta={**run_meta, "step": at})

    def save(at: int, loss: float) -> None:
        m = {**run_meta, "step": at, "best_val_l1": best_l1[0] if math.isfinite(best_l1[0]) else None, "log": log}
        save_checkpoint(out_dir / "last", model, backgrounds=backgrounds, meta=m, optimizer=optimizer, scheduler=scheduler)
        write_json(out_dir / "train_log.json", m)  # with last/: the curve up to the step it holds

    step = optimise(step, train_config.steps, batch_loss, optimizer, scheduler, list(model.parameters()), save,
                    train_config.save_every, "train ACT", rank=rank, grad_clip=train_config.grad_clip,
                    after_step=after_step, state=str(out_dir / "last"), progress=progress)
    elapsed = time.perf_counter() - t0
    if world > 1:
        dist.destroy_process_group()
    return {"steps": step, "samples_per_s": samples[0] / elapsed if elapsed > 0 else None,
            "best_val_l1": best_l1[0] if math.isfinite(best_l1[0]) else None,
            "final_loss": log["train"][-1]["loss"] if log["train"] else None, "world_size": world}


def resolve_checkpoint(path: str | Path) -> Path:
    """A checkpoint folder, or a training output folder (then its ``best``, else its ``last``)."""
    path = Path(path)
    if (path / "config.json").is_file():
        return path
    for sub in ("best", "last"):
        if (path / sub / "config.json").is_file():
            return path / sub
    raise CheckpointError(f"no ACT checkpoint at {path} (expected config.json there or in best/ or last/)")


def train_on_folder(dataset: str | Path, out_dir: str | Path, *, preset: str = "cpu", train_config: ACTTrainConfig,
                    val_fraction: float = 0.1, augment=None, resume: bool = False, overwrite: bool = False,
                    stats_path=None,
                    tactile_sensors=None, split_seed: int | None = None, progress: bool = True,
                    data_options: dict | None = None, **act_overrides) -> dict:
    """Train ACT on a folder of episodes; the ACT config's data fields come from the episodes.

    tactile_sensors: tactile streams the policy reads (None = every one recorded; () = vision only).
    data_options: how to read the data (``load_training_data``): a LeRobot v3.0 folder's {"tactile_keys": [...],
        "force_keys": {...}}, for either kind "background_images" (None: the defaults).
    split_seed: seed of the train / validation split by episode (None = ``train_config.seed``), so that
        training seeds can vary on one split (and one ForceAugment cache).
    augment: optional ``AugmentStage`` (``controltac_il.datasets.stage``: e.g. ForceAugment copies of the training
        split); validation always stays on the recorded episodes. The run records its settings and its summary.
    act_overrides: ACTConfig fields to change from the preset (e.g. chunk_size).
    resume / overwrite: see :func:`train`; the output folder is checked before the data is read.
    """
    from policies.act.data import check_compatible, load_training_data  # noqa: PLC0415 (h5py only when used)

    chunk = act_overrides.get("chunk_size", ACTConfig.from_preset(preset).chunk_size)
    split = train_config.seed if split_seed is None else split_seed
    claim_output(out_dir, RUN_OUTPUTS, resume=resume or overwrite, tool="train_act.py")  # before any slow work
    if resume and not (Path(out_dir) / "last").is_dir():
        raise CheckpointError(f"--resume: no checkpoint to continue from at {Path(out_dir) / 'last'}")
    data = load_training_data(dataset, chunk, val_fraction, split, stats_path, tactile_sensors, data_options)
    if chunk > data.longest_episode:
        raise ValueError(f"chunk_size {chunk} (--chunk-size) is longer than every episode of {dataset} (the longest "
                         f"has {data.longest_episode} frames): most of each action chunk would be padding; use "
                         f"--chunk-size {data.longest_episode} or less")
    act_config = ACTConfig.from_preset(preset, camera_names=data.spec.camera_names,
                                       tactile_names=data.spec.tactile_names, state_dim=data.spec.state_dim,
                                       action_dim=data.spec.action_dim, **act_overrides)
    check_compatible(act_config, data.spec, where=str(dataset))
    augmented = augment(data.train) if augment is not None else None
    train_set = augmented.dataset if augmented is not None else data.train
    meta = {"dataset": str(Path(dataset).resolve()), "episodes": data.n_episodes, "val_episodes": data.val_episodes,
            "train_frames": len(train_set), "episode_backgrounds": data.background_digests,
            "tactile_backgrounds": image_digests(data.backgrounds),
            "augment": None if augment is None else {**augment.description, "summary": augmented.summary}}
    summary = train(act_config, train_config, train_set, data.val, out_dir, stats=data.stats,
                    backgrounds=data.backgrounds, resume=resume, overwrite=overwrite, meta=meta, progress=progress)
    return {**summary, **meta}
