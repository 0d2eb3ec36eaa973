"""The stage-2 training job: the pose adapter over a frozen stage-1 generator, on sensor-model scenes.

``run`` takes a parsed ``PoseTrainConfig`` (``python -m controltac_il.generator.training stage2``). Data:
``pose_data.render_scenes`` (the six training objects plus ``--procedural`` random shapes, each in ``--scenes``
scenes on random training sensor instances, ``--poses`` x ``--forces`` frames per scene), rendered in memory and
encoded once by the frozen autoencoder. Pairs within a scene; the condition is the reference's contact mask carried
to the target pose with the paper's alignment noise (±3 px, ±1°). Loss as stage 1's (0.5 L1 + 0.5 MSE on the
normalised latent change, ``--one-step-fraction`` at the last timestep); AdamW with warm-up and cosine decay; the
EMA of the adapter is shipped (fp16, ``OUT/final``): that of the state save with the lowest error on
``--val-objects`` procedural shapes it never trains on (its own validation split; the benchmark's held-out objects
are never looked at). The stage-1 weights are never changed.

Run folder: ``train_config.json``, ``adapter_state.{safetensors,json}`` (periodic, atomic), ``adapter_best.safetensors``
(the best validation step's EMA weights), ``final/``. ``--resume`` continues with the saved run's data and model
(only ``--steps``, ``--checkpoint-every``, ``--threads``, ``--device`` may change; anything else, or another
``--base``, is refused).
"""

from __future__ import annotations

import dataclasses
import json
import platform
import time
from pathlib import Path

import numpy as np
import torch
from diffusers.training_utils import EMAModel

from controltac_il.checkpoint import read_json
from controltac_il.generator.adapter import PoseAdapter, masks_to_model
from controltac_il.generator.checkpoint import checkpoint_hash, load_adapter, load_checkpoint, save_adapter
from controltac_il.generator.config import PoseAdapterConfig
from controltac_il.generator.dit import force_condition
from controltac_il.generator.pipeline import ForceGenerator, residual_to_unit
from controltac_il.generator.sampler import make_scheduler
from controltac_il.generator.shipped import SHIPPED_ADAPTERS, locate_checkpoint
from controltac_il.generator.training.config import STAGE2_PROG as PROG, RESUMABLE_CHANGES, PoseTrainConfig
from controltac_il.generator.training.objectives import ema_weights, noised_batch, prediction_loss, restore_ema
from controltac_il.generator.training.pose_data import render_scenes, sample_pose_pairs, target_mask
from controltac_il.generator.training.validation import (VAL_PAIRS, BestOnValidation, Validation, distinct_pairs,
                                                         generation_error)
from controltac_il.io import write_json
from controltac_il.run_state import load_run_state, save_run_state
from controltac_il.tactile.indenters import TRAIN_OBJECTS, procedural_objects
from controltac_il.training import device_name, lr_schedule, optimise


@torch.no_grad()
def encode_scenes(ae, residuals: np.ndarray, size: tuple[int, int], batch: int = 128) -> torch.Tensor:
    """Raw latents (N, C, h, w) of uint8 residuals (N, h0, w0, 3), resized to the model's ``size``."""
    import cv2

    h, w = size
    out = []
    for s in range(0, len(residuals), batch):
        chunk = np.stack([cv2.resize(r, (w, h), interpolation=cv2.INTER_AREA) for r in residuals[s:s + batch]])
        out.append(ae.encode(residual_to_unit(torch.from_numpy(chunk))))
    return torch.cat(out)


def _check_resume(cfg: PoseTrainConfig, out: Path) -> None:
    """A resumed run must keep the saved run's data and model (only RESUMABLE_CHANGES may differ)."""
    if (out / "train_config.json").is_file():
        saved = read_json(out / "train_config.json")
        changed = sorted(k for k, v in dataclasses.asdict(cfg).items()
                         if k not in RESUMABLE_CHANGES and json.loads(json.dumps(v)) != saved.get(k))
        if changed:
            raise ValueError(f"--resume: {out} was trained with other {', '.join('--' + k.replace('_', '-') for k in changed)}"
                             "; continue it with its own settings or choose another --out")


def _adapter(cfg: PoseTrainConfig, acfg: PoseAdapterConfig, dit) -> tuple[PoseAdapter, dict | None]:
    """The adapter to train: zero-initialised, or ``--adapter-from``'s weights (same base and widths); and the
    source's model card (None without one)."""
    torch.manual_seed(cfg.seed + 1)
    adapter = PoseAdapter(acfg, dit)
    if cfg.adapter_from is None:
        return adapter, None
    folder = locate_checkpoint(cfg.adapter_from, SHIPPED_ADAPTERS)
    source, weights = load_adapter(folder)
    if (source.base_hash, source.mask_channels, source.head_width) != (acfg.base_hash, acfg.mask_channels, acfg.head_width):
        raise ValueError(f"--adapter-from {folder}: trained over another --base or with other widths")
    adapter.load_state_dict(weights.state_dict())
    return adapter, read_json(folder / "model_card.json")


def _card(cfg: PoseTrainConfig, acfg: PoseAdapterConfig, adapter, source_card, meta: dict, data: dict, t0: float,
          dev: torch.device) -> dict:
    """The shipped adapter's model card: command, lineage, data and the cost of training."""
    command = " ".join([PROG, *(f"--{k.replace('_', '-')} {' '.join(map(str, v)) if isinstance(v, (tuple, list)) else v}"
                                for k, v in dataclasses.asdict(cfg).items() if v is not None)])
    return {"trained_by": PROG, "command": command, "base": str(cfg.base),
            "adapter_from": None if source_card is None else {"path": str(cfg.adapter_from), "command":
                                                              source_card.get("command"), "training": source_card.get("training")},
            "base_hash": acfg.base_hash, "train_config": dataclasses.asdict(cfg), "data": data,
            "training": {"steps": meta["step"], "final_loss": meta["loss"], "wall_s": round(meta["wall_s"], 1),
                         "total_s": round(time.perf_counter() - t0, 1), "machine": platform.processor() or platform.machine(),
                         "threads": torch.get_num_threads(), "torch": torch.__version__,
                         "device": device_name(dev)},
            "parameters": sum(p.numel() for p in adapter.parameters()), "validation": meta.get("validation")}


def _validation(cfg: PoseTrainConfig, gcfg, ae, dit, dev: torch.device) -> Validation | None:
    """The run's validation split: ``cfg.val_objects`` procedural shapes it never trains on, two scenes each,
    ``VAL_PAIRS`` cross-pose pairs (at most as many as there are) with exact target masks; its error is that of the adapter over the frozen base."""
    if cfg.val_objects == 0:
        return None
    names = procedural_objects(cfg.procedural + cfg.val_objects)[cfg.procedural:]
    scenes = render_scenes(names, 2, cfg.poses, cfg.forces, cfg.seed + 1, cfg.size, "train", cfg.instances)
    rng = np.random.default_rng([cfg.seed, 23])
    members = [m for m in scenes.members() if len(m) >= 2]
    count = min(VAL_PAIRS, distinct_pairs(members))
    pairs = np.stack([rng.choice(members[s], size=2, replace=False) for s in rng.integers(0, len(members), size=count)])
    ref, tgt = scenes.residuals[pairs[:, 0]], scenes.residuals[pairs[:, 1]]
    delta = scenes.forces[pairs[:, 1]] - scenes.forces[pairs[:, 0]]
    masks = np.stack([target_mask(scenes, r, t) for r, t in pairs])
    return Validation(tuple(names), len(pairs), lambda adapter: generation_error(
        ForceGenerator(gcfg, ae, dit, device=dev, pose_adapter=adapter), ref, tgt, delta,
        reference_force=scenes.forces[pairs[:, 0]], mask=masks))


def _fit(cfg: PoseTrainConfig, gcfg, acfg: PoseAdapterConfig, adapter, dit, scenes, z: torch.Tensor, stem: Path,
         dev: torch.device, validation: Validation | None = None) -> dict:
    """AdamW (+ EMA) on the adapter, resumable from ``stem``; leaves the EMA weights in ``adapter``: the last
    step's, or with ``validation`` the best state save's. Returns the final state's metadata."""
    ema = EMAModel(adapter.parameters(), decay=cfg.ema_decay, update_after_step=-1)
    opt = torch.optim.AdamW(adapter.parameters(), lr=cfg.lr, weight_decay=0.0)
    meta: dict = {"step": 0, "wall_s": 0.0}
    if stem.with_suffix(".json").is_file():
        saved = read_json(stem.with_suffix(".json")).get("config")  # as written, before any later config field
        if saved is None or PoseAdapterConfig.from_dict(saved) != acfg:
            raise ValueError(f"--resume: {stem}.json was trained over another stage-1 checkpoint than --base {cfg.base}")
        meta, tensors = load_run_state(stem, {"adapter": adapter}, opt)
        restore_ema(ema, adapter, tensors, meta["ema_step"])
    sched = lr_schedule(opt, [cfg.lr], cfg.steps, cfg.warmup_steps, cfg.min_lr_ratio * cfg.lr, meta.get("lr_schedule"),
                        meta["step"])
    noise_sched, members = make_scheduler(gcfg.diffusion), scenes.members()
    c = gcfg.autoencoder.latent_channels
    lat_s, dlt_s = (torch.tensor(v, device=dev).view(1, c, 1, 1) for v in (gcfg.latent_scale, gcfg.delta_scale))
    t_run = time.perf_counter()
    best = None if validation is None else BestOnValidation(validation, stem.parent / "adapter_best.safetensors",
                                                            meta.get("validation"))

    def batch_loss(step: int) -> torch.Tensor:
        rng = np.random.default_rng([cfg.seed, 5, step])
        ref, tgt, df, masks = sample_pose_pairs(scenes, members, cfg.batch, rng, cfg.alignment_px, cfg.alignment_deg)
        condition = torch.from_numpy(force_condition(df, scenes.forces[ref], gcfg.dit)).to(dev)
        ref, tgt = torch.from_numpy(ref).to(dev), torch.from_numpy(tgt).to(dev)
        x0 = (z[tgt] - z[ref]) / dlt_s
        x_t, t, target = noised_batch(gcfg, noise_sched, x0, cfg.one_step_fraction, int(rng.integers(0, 2**62)))
        m = torch.from_numpy(masks_to_model(masks, gcfg.image_size)).to(dev)
        return prediction_loss(adapter(dit, x_t, z[ref] / lat_s, t, condition, m), target)

    def save(step: int, loss: float) -> None:
        if best is not None:
            best.measure(step, adapter, ema)
        save_run_state(stem, {"adapter": adapter, "ema": ema_weights(ema, adapter)},
                       {"step": step, "loss": loss, "wall_s": meta["wall_s"] + time.perf_counter() - t_run,
                        "config": acfg.to_dict(), "ema_step": ema.optimization_step,
                        **({} if best is None else {"validation": best.record})}, opt, sched)

    optimise(meta["step"], cfg.steps, batch_loss, opt, sched, list(adapter.parameters()), save, cfg.checkpoint_every,
             "pose adapter", after_step=lambda step, out: ema.step(adapter.parameters()), state=str(stem))
    meta, tensors = load_run_state(stem, {"adapter": adapter})
    adapter.load_state_dict({k[len("ema."):]: v for k, v in tensors.items() if k.startswith("ema.")})
    if best is not None and meta.get("validation", {}).get("best_step") is not None:
        best.load_best(adapter)
    return meta


def run(cfg: PoseTrainConfig) -> Path:
    """Train per ``cfg``; returns ``<out>/final``."""
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    out = Path(cfg.out)
    t0 = time.perf_counter()
    base_dir = locate_checkpoint(cfg.base)
    gcfg, ae, dit = load_checkpoint(base_dir)  # a bad --base leaves --out as it was
    out.mkdir(parents=True, exist_ok=True)
    _check_resume(cfg, out)
    write_json(out / "train_config.json", dataclasses.asdict(cfg))
    dev = torch.device(cfg.device)
    ae.requires_grad_(False)
    dit.requires_grad_(False).to(dev)
    objects = [*TRAIN_OBJECTS, *procedural_objects(cfg.procedural)]
    scenes = render_scenes(objects, cfg.scenes, cfg.poses, cfg.forces, cfg.seed, cfg.size, "train", cfg.instances)
    z = encode_scenes(ae.to(dev), scenes.residuals, gcfg.image_size)
    acfg = PoseAdapterConfig(base=gcfg, base_hash=checkpoint_hash(base_dir), mask_channels=cfg.mask_channels,
                             head_width=cfg.head_width, alignment_px=cfg.alignment_px, alignment_deg=cfg.alignment_deg)
    adapter, source_card = _adapter(cfg, acfg, dit)
    adapter = adapter.to(dev)
    meta = _fit(cfg, gcfg, acfg, adapter, dit, scenes, z, out / "adapter_state", dev, _validation(cfg, gcfg, ae, dit, dev))
    adapter.cpu()
    data = {"objects": len(objects), "scenes": len(scenes.objects), "frames": len(scenes.residuals),
            "size": list(cfg.size), "sensor_family": "train", "instances": cfg.instances}
    card = _card(cfg, acfg, adapter, source_card, meta, data, t0, dev)
    final = save_adapter(out / "final", acfg, adapter, dtype=torch.float16, model_card=card)
    print(f"wrote {final}")
    return final
