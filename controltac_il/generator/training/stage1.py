"""The stage-1 training job: the force-control generator's autoencoder, then its DiT on cached latents.

``run`` takes a parsed ``GeneratorTrainConfig`` (``python -m controltac_il.generator.training stage1``) through three
parts, each resumable from its state in the run folder and alike on every torchrun rank: the autoencoder (trained,
reused or fine-tuned), the latents it gives the dataset (cached), and the DiT denoiser on them.

Run folder (never the dataset folder)::

    train_config.json                      the arguments
    autoencoder_state.{safetensors,json}   autoencoder + AdamW + LR-schedule state, step (periodic, atomic)
    autoencoder_finetune_state.{...}       the same for a reused autoencoder's fine-tune (--ae-finetune-steps)
    latents.safetensors                    the dataset encoded once (the DiT trains on these)
    denoiser_state.{safetensors,json}      DiT + EMA + AdamW + LR-schedule state, step (periodic, atomic)
    denoiser_best.safetensors              with --val-objects: the EMA weights of the best validation step so far
    final/                                 the inference checkpoint (fp16) + model_card.json

The autoencoder: L1 + MSE + image-gradient L1 on random crops of residuals in [-1, 1].
The DiT: pairs of the same contact pose; x0 = (z_target - z_ref) / delta_scale, noised by the DDPM schedule; loss
0.5 L1 + 0.5 MSE on the noise (or on x0 for ``--prediction-type sample``); AdamW, linear warm-up then cosine decay
to ``min_lr_ratio`` of the peak (torch schedulers, ``controltac_il.training.lr_schedule``); EMA weights (diffusers'
``EMAModel``) are shipped: with ``--val-objects N``, those of the periodic save with the lowest error on N held-out
objects (the run's own validation split; the benchmark's unseen objects and sensor are never looked at), else the
last step's.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from diffusers.training_utils import EMAModel
from safetensors.torch import load_file, save_file
from tqdm.auto import tqdm

from controltac_il.checkpoint import read_json
from controltac_il.generator.autoencoder import TactileAutoencoder, autoencoder_loss
from controltac_il.generator.checkpoint import load_checkpoint, save_checkpoint
from controltac_il.generator.config import AutoencoderConfig, DiffusionConfig, GeneratorConfig
from controltac_il.generator.dit import ForceDiT, force_condition
from controltac_il.generator.pipeline import ForceGenerator, residual_to_unit
from controltac_il.generator.sampler import make_scheduler
from controltac_il.generator.training.config import (DIT_PRESETS, GeneratorTrainConfig, legacy_provenance, model_card,
                                                     provenance)
from controltac_il.generator.training.data import PairData, crop_batch, load_pair_data, new_contact, sample_pairs
from controltac_il.generator.training.objectives import ema_weights, noised_batch, prediction_loss, restore_ema
from controltac_il.generator.training.validation import (BestOnValidation, Validation, generation_error,
                                                         hold_out_objects)
from controltac_il.io import atomic_path, write_json
from controltac_il.run_state import load_run_state, save_run_state
from controltac_il.training import barrier, lr_schedule, optimise, setup_distributed, wrap


# -- the autoencoder ---------------------------------------------------------------------------

def fit_autoencoder(cfg: GeneratorTrainConfig, ae: TactileAutoencoder, data: PairData, out: Path, rank: int, world: int,
                    steps: int, state: str, stream: int, desc: str, extra: dict) -> dict:
    """AdamW on all of ``ae``'s weights for ``steps`` steps on random crops of ``data`` (the loss of
    ``autoencoder_loss``; crops drawn from the rng stream ``stream``), resumable from ``out/<state>``; ``extra``
    joins the saved state's metadata. Returns that metadata."""
    dev = torch.device(cfg.device)
    ae.to(dev)
    opt = torch.optim.AdamW(ae.parameters(), lr=cfg.ae_lr, weight_decay=0.0)
    stem = out / state
    meta = {"step": 0, "wall_s": 0.0}
    if stem.with_suffix(".json").is_file():
        meta, _ = load_run_state(stem, {"autoencoder": ae}, opt)
    sched = lr_schedule(opt, [cfg.ae_lr], steps, cfg.warmup_steps, cfg.min_lr_ratio * cfg.ae_lr,
                        meta.get("lr_schedule"), meta["step"])
    model, per_rank, t0 = wrap(ae, world), max(1, cfg.ae_batch // world), time.perf_counter()

    def batch_loss(step: int) -> torch.Tensor:
        x = crop_batch(data, np.random.default_rng([cfg.seed, stream, rank, step]), per_rank, cfg.ae_crop).to(dev)
        return autoencoder_loss(model(x), x, cfg.ae_contact_weight)

    def save(step: int, loss: float) -> None:
        save_run_state(stem, {"autoencoder": ae}, {"step": step, "wall_s": meta["wall_s"] + time.perf_counter() - t0,
                                                   "loss": loss, **extra, "trained_by": provenance(cfg)}, opt, sched)

    optimise(meta["step"], steps, batch_loss, opt, sched, list(ae.parameters()), save, cfg.checkpoint_every, desc,
             rank=rank, state=str(stem))
    barrier(world)
    if stem.with_suffix(".json").is_file():  # every rank reads rank 0's final state (identical weights anyway under DDP)
        meta, _ = load_run_state(stem, {"autoencoder": ae})
    return meta


def train_autoencoder(cfg: GeneratorTrainConfig, data: PairData, out: Path, rank: int, world: int) -> tuple[TactileAutoencoder, dict]:
    torch.manual_seed(cfg.seed)
    ae_cfg = AutoencoderConfig(image_size=cfg.image_size, channels=cfg.ae_channels, latent_channels=cfg.latent_channels)
    ae = TactileAutoencoder(ae_cfg)
    meta = fit_autoencoder(cfg, ae, data, out, rank, world, cfg.ae_steps, "autoencoder_state", 1, "autoencoder",
                           {"config": ae_cfg.to_dict()})
    return ae.eval(), meta


def finetune_autoencoder(cfg: GeneratorTrainConfig, ae: TactileAutoencoder, ae_meta: dict, data: PairData, out: Path,
                         rank: int, world: int) -> tuple[TactileAutoencoder, dict]:
    """Fine-tune a reused autoencoder (encoder and decoder) for ``cfg.ae_finetune_steps`` on this run's data;
    ``ae_meta`` gains ``finetune`` (steps, cost, command). Its latent space moves: the DiT trains after it."""
    torch.manual_seed(cfg.seed + 2)
    meta = fit_autoencoder(cfg, ae, data, out, rank, world, cfg.ae_finetune_steps, "autoencoder_finetune_state", 4,
                           "autoencoder fine-tune", {})
    return ae.eval(), {**ae_meta, "finetune": {k: meta.get(k) for k in ("step", "wall_s", "loss", "trained_by")}}


def reuse_autoencoder(src: Path) -> tuple[TactileAutoencoder, dict]:
    """The trained autoencoder of another run folder (its state) or of a checkpoint folder (its weights),
    with the training that made it (``trained_by``: command and data) where the source records it."""
    stem = src / "autoencoder_state"
    if stem.with_suffix(".json").is_file():
        meta = read_json(stem.with_suffix(".json"))
        ae = TactileAutoencoder(AutoencoderConfig.from_dict(meta["config"]))
        load_run_state(stem, {"autoencoder": ae})
        if "trained_by" not in meta:  # states written before it was recorded: the run's saved arguments
            meta["trained_by"] = legacy_provenance(src)
        return ae.eval(), {**meta, "from": str(src)}
    config, ae, _ = load_checkpoint(src)
    card = read_json(src / "model_card.json") if (src / "model_card.json").is_file() else {}
    a = card.get("autoencoder", {})
    return ae.eval(), {"step": a.get("steps"), "wall_s": a.get("wall_s"), "loss": a.get("final_loss"),
                       "trained_by": a.get("trained_by"), "from": str(src), "config": config.autoencoder.to_dict()}


# -- latents -----------------------------------------------------------------------------------

@torch.no_grad()
def encode_all(ae: TactileAutoencoder, data: PairData, batch: int = 64) -> torch.Tensor:
    """Latents of every residual of ``data``, float32 (N, C, h, w) on the CPU, encoded where ``ae`` is."""
    dev = next(ae.parameters()).device
    zs = [ae.encode(residual_to_unit(torch.from_numpy(data.residuals[s:s + batch]).to(dev))).cpu()
          for s in tqdm(range(0, len(data.residuals), batch), desc="encoding dataset", unit="batch", disable=None)]
    return torch.cat(zs)


def latent_scales(z: torch.Tensor, data: PairData, seed: int, pairs: int = 4096) -> tuple[list[float], list[float]]:
    """Per-channel std of latents and of same-pose latent differences (self pairs excluded)."""
    latent = z.std(dim=(0, 2, 3)).clamp_min(1e-3)
    rng = np.random.default_rng([seed, 3])
    ref, tgt, _ = sample_pairs(data, pairs, rng, no_contact_prob=0.0)
    keep = ref != tgt
    d = z[tgt[keep]] - z[ref[keep]]
    delta = d.std(dim=(0, 2, 3)).clamp_min(1e-3) if keep.any() else torch.ones_like(latent)
    return latent.tolist(), delta.tolist()


def cached_latents(cfg: GeneratorTrainConfig, ae: TactileAutoencoder, data: PairData, out: Path, rank: int, world: int) -> torch.Tensor:
    path = out / "latents.safetensors"
    if rank == 0 and not path.is_file():
        z = encode_all(ae.to(cfg.device), data)
        ae.cpu()
        with atomic_path(path) as tmp:
            save_file({"latents": z.contiguous()}, str(tmp))
    barrier(world)
    z = load_file(str(path))["latents"]
    if z.shape[0] != len(data.residuals):
        raise ValueError(f"{path} holds {z.shape[0]} latents but the dataset has {len(data.residuals)} images; delete it")
    return z


# -- the DiT -----------------------------------------------------------------------------------

def source_denoiser(src: Path) -> tuple[GeneratorConfig, dict[str, torch.Tensor]]:
    """(config, float32 DiT weights) of a run folder's latest state (its EMA) or of a checkpoint folder."""
    stem = src / "denoiser_state"
    if stem.with_suffix(".json").is_file():
        meta, tensors = load_run_state(stem, {})
        config = GeneratorConfig.from_dict(meta["config"])
        return config, {k[len("ema."):]: v.float() for k, v in tensors.items() if k.startswith("ema.")}
    if not (src / "config.json").is_file():
        raise FileNotFoundError(f"denoiser_from: {src} holds neither a denoiser_state.json (run folder) nor a config.json (checkpoint)")
    config, _, dit = load_checkpoint(src)
    return config, dit.state_dict()


def check_same_models(src: Path, source: GeneratorConfig, gcfg: GeneratorConfig) -> None:
    """ValueError naming the fields where the source's networks differ from this run's; a run may add the
    reference-force condition to a source without it (its embedder starts at zero)."""
    for part in ("dit", "autoencoder"):
        a, b = getattr(source, part).to_dict(), getattr(gcfg, part).to_dict()
        diff = {k: (a.get(k), b.get(k)) for k in a.keys() | b.keys() if a.get(k) != b.get(k)
                and not (k == "reference_force" and not a.get(k) and b.get(k))}
        if diff:
            raise ValueError(f"denoiser_from: {src} has another {part} config than this run "
                             f"(field: (source, this run)): {diff}")


def restore_denoiser(stem: Path, dit: ForceDiT, ema: EMAModel, opt: torch.optim.Optimizer | None = None) -> dict:
    """Load a denoiser state into ``dit``, ``ema`` (and ``opt``); returns its metadata. States written before the
    EMA's step count was recorded count one EMA update per step, as they were made. A state of a DiT with the
    other reference-force condition is refused naming the flag (ValueError)."""
    saved = read_json(stem.with_suffix(".json")).get("config", {}).get("dit", {}).get("reference_force", False)
    if saved != dit.config.reference_force:
        raise ValueError(f"--resume: {stem.parent} was trained {'with' if saved else 'without'} --reference-force; "
                         f"resume it {'with' if saved else 'without'} it, or start another --out")
    meta, tensors = load_run_state(stem, {"denoiser": dit}, opt)
    restore_ema(ema, dit, tensors, meta.get("ema", {}).get("optimization_step", meta["step"]))
    return meta


def denoiser_loss(cfg: GeneratorTrainConfig, gcfg: GeneratorConfig, sched, z: torch.Tensor, data: PairData,
                  model: torch.nn.Module, rank: int, step: int, per_rank: int) -> torch.Tensor:
    """0.5 L1 + 0.5 MSE of the DiT's prediction (noise or x0) on one batch of same-pose latent pairs (a share
    ordered to press harder, ``increase_prob``); with ``new_contact_weight`` w, latent cells of new contact weigh
    1 + w; ``sched``: the training noise schedule (diffusers)."""
    c, dev = gcfg.autoencoder.latent_channels, z.device
    rng = np.random.default_rng([cfg.seed, 2, rank, step])
    ref_i, tgt_i, df = sample_pairs(data, per_rank, rng, cfg.no_contact_prob, cfg.distinct_pairs, cfg.increase_prob)
    ref, tgt = torch.from_numpy(ref_i).to(dev), torch.from_numpy(tgt_i).to(dev)
    x0 = (z[tgt] - z[ref]) / torch.tensor(gcfg.delta_scale, device=dev).view(1, c, 1, 1)
    zr = z[ref] / torch.tensor(gcfg.latent_scale, device=dev).view(1, c, 1, 1)
    x_t, t, target = noised_batch(gcfg, sched, x0, cfg.one_step_fraction, int(rng.integers(0, 2**62)))
    weight = None
    if cfg.new_contact_weight > 0:
        new = new_contact(data, ref_i, tgt_i, data.residuals.shape[1] // z.shape[-2])
        weight = 1.0 + cfg.new_contact_weight * torch.from_numpy(new).to(dev)
    condition = force_condition(df, data.forces[ref_i], gcfg.dit)
    return prediction_loss(model(x_t, zr, t, torch.from_numpy(condition).to(dev)), target, weight)


def train_denoiser(cfg: GeneratorTrainConfig, gcfg: GeneratorConfig, z: torch.Tensor, data: PairData, out: Path,
                   rank: int, world: int, init: dict[str, torch.Tensor] | None = None,
                   validation: Validation | None = None) -> tuple[ForceDiT, dict]:
    """Train (or resume) the DiT; ``init``: starting weights when there is no state to resume. Returns the EMA
    weights of the last step, or with ``validation`` those of the best periodic save (``meta["validation"]``)."""
    torch.manual_seed(cfg.seed + 1)
    dit, z = ForceDiT(gcfg.dit), z.to(cfg.device)
    if init is not None:
        missing, unexpected = dit.load_state_dict(init, strict=False)
        if unexpected or any(not k.startswith("r_embedder.") for k in missing):  # only a new reference embedder
            raise ValueError(f"denoiser_from: its DiT weights do not fit this run's DiT (missing {missing}, "
                             f"unexpected {unexpected})")
    dit.to(cfg.device)
    ema = EMAModel(dit.parameters(), decay=cfg.ema_decay, update_after_step=-1)  # decay min(ema_decay, (1+n)/(10+n))
    opt = torch.optim.AdamW(dit.parameters(), lr=cfg.dit_lr, weight_decay=0.0)
    stem = out / "denoiser_state"
    meta = restore_denoiser(stem, dit, ema, opt) if stem.with_suffix(".json").is_file() else {"step": 0, "wall_s": 0.0}
    sched = lr_schedule(opt, [cfg.dit_lr], cfg.dit_steps, cfg.warmup_steps, cfg.min_lr_ratio * cfg.dit_lr,
                        meta.get("lr_schedule"), meta["step"])
    # one entry per (re)start: resumed runs may change the step budget or the prediction target
    history = meta.get("history", []) + [{"from_step": meta["step"], "dit_steps": cfg.dit_steps, "lr": cfg.dit_lr,
                                          "prediction_type": gcfg.diffusion.prediction_type, "batch": cfg.dit_batch,
                                          "one_step_fraction": cfg.one_step_fraction, "denoiser_from": cfg.denoiser_from,
                                          "increase_prob": cfg.increase_prob, "new_contact_weight": cfg.new_contact_weight,
                                          "reference_force": cfg.reference_force}]
    best = None if validation is None else BestOnValidation(validation, out / "denoiser_best.safetensors", meta.get("validation"))
    model, per_rank, t0 = wrap(dit, world), max(1, cfg.dit_batch // world), time.perf_counter()
    noise_sched = make_scheduler(gcfg.diffusion)

    def save(step: int, loss: float) -> None:
        if best is not None:
            best.measure(step, dit, ema)
        save_run_state(stem, {"denoiser": dit, "ema": ema_weights(ema, dit)},
                       {"step": step, "wall_s": meta["wall_s"] + time.perf_counter() - t0, "loss": loss,
                        "config": gcfg.to_dict(), "history": history, "ema": {"optimization_step": ema.optimization_step},
                        **({} if best is None else {"validation": best.record})}, opt, sched)

    optimise(meta["step"], cfg.dit_steps, lambda step: denoiser_loss(cfg, gcfg, noise_sched, z, data, model, rank, step, per_rank),
             opt, sched, list(dit.parameters()), save, cfg.checkpoint_every, f"denoiser ({cfg.dit_preset})", rank=rank,
             after_step=lambda step, out: ema.step(dit.parameters()), state=str(stem))
    barrier(world)
    if stem.with_suffix(".json").is_file():
        meta = restore_denoiser(stem, dit, ema)
    ema.copy_to(dit.parameters())
    if best is not None and meta.get("validation", {}).get("best_step") is not None:
        best.load_best(dit)
    return dit.eval(), meta


# -- driver ------------------------------------------------------------------------------------

def autoencoder_for(cfg: GeneratorTrainConfig, data: PairData, out: Path, rank: int, world: int) -> tuple[TactileAutoencoder, dict]:
    """The run's autoencoder: reused from ``--autoencoder-from`` (fine-tuned with ``--ae-finetune-steps``), trained (stages "all", "autoencoder") or this run's."""
    if cfg.autoencoder_from is not None:
        ae, ae_meta = reuse_autoencoder(Path(cfg.autoencoder_from))
        if tuple(ae.config.image_size) != cfg.image_size:
            raise ValueError(f"--autoencoder-from has image_size {ae.config.image_size}, this run {cfg.image_size}")
        return finetune_autoencoder(cfg, ae, ae_meta, data, out, rank, world) if cfg.ae_finetune_steps else (ae, ae_meta)
    if cfg.stage in ("all", "autoencoder"):
        return train_autoencoder(cfg, data, out, rank, world)
    return reuse_autoencoder(out)


def run(cfg: GeneratorTrainConfig) -> Path:
    """Train per ``cfg``; returns the final checkpoint folder (``<out>/final``)."""
    rank, world = setup_distributed()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    out = Path(cfg.out)
    t_start = time.perf_counter()
    data = load_pair_data(cfg.data, cfg.image_size, cfg.no_contact_frames, cfg.seed, progress=rank == 0)
    train_data, split = hold_out_objects(data, cfg.val_objects, cfg.seed)
    if rank == 0:  # only once --data is read: data refused leaves --out as it was
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "train_config.json", {**dataclasses.asdict(cfg), "world_size": world})
    barrier(world)
    ae, ae_meta = autoencoder_for(cfg, train_data, out, rank, world)
    if cfg.stage == "autoencoder":
        return out

    z = cached_latents(cfg, ae, data, out, rank, world)
    source, init = (None, None) if cfg.denoiser_from is None else source_denoiser(Path(cfg.denoiser_from))
    lat, dsc = latent_scales(z, train_data, cfg.seed) if source is None else (source.latent_scale, source.delta_scale)
    gcfg = GeneratorConfig(
        autoencoder=ae.config,
        dit=DIT_PRESETS[cfg.dit_preset](in_channels=ae.config.latent_channels, patch_size=cfg.dit_patch,
                                        conv_head_width=cfg.dit_conv_head),
        diffusion=DiffusionConfig(prediction_type=cfg.prediction_type, default_steps=cfg.default_steps),
        latent_scale=lat, delta_scale=dsc, anchor_to_reference=cfg.anchor_to_reference, detail_gate=cfg.detail_gate,
    )
    if cfg.reference_force:
        gcfg = dataclasses.replace(gcfg, dit=dataclasses.replace(gcfg.dit, reference_force=True))
    if source is not None:
        check_same_models(Path(cfg.denoiser_from), source, gcfg)
    validate = None if split is None else Validation(split.objects, len(split.ref), lambda d: generation_error(
        ForceGenerator(gcfg, ae, d, device=cfg.device), data.residuals[split.ref], data.residuals[split.tgt], split.delta,
        reference_force=data.forces[split.ref]))
    dit, dit_meta = train_denoiser(cfg, gcfg, z, train_data, out, rank, world, init, validate)
    final, ae, dit = out / "final", ae.cpu(), dit.cpu()
    if rank == 0:
        card = model_card(cfg, train_data, ae, ae_meta, dit, dit_meta, world, time.perf_counter() - t_start)
        save_checkpoint(final, gcfg, ae, dit, dtype=torch.float16, model_card=card)
        print(f"wrote {final}")
    barrier(world)
    if world > 1:
        dist.destroy_process_group()
    return final
