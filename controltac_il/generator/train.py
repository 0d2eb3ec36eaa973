"""Train the force-control generator: autoencoder first, then the DiT on cached latents.

    python -m controltac_il.generator.train --data DATASET --out RUN_DIR            # both stages
    python -m controltac_il.generator.train --data DATASET --out RUN_DIR --resume   # continue
    python -m controltac_il.generator.train --data DATASET --out FAST_RUN --autoencoder-from RUN_DIR \
        --dit-preset tiny --prediction-type sample --default-steps 2                  # faster variant
    python -m controltac_il.generator.train --data NEW_DATASET --out TUNED --autoencoder-from RUN_DIR \
        --stage denoiser --denoiser-from RUN_DIR [same DiT flags] --dit-lr 3e-4        # fine-tune on new poses
    python -m controltac_il.generator.train --data MY_PRESSES --out TUNED --autoencoder-from default \
        --ae-finetune-steps 600 --ae-lr 2e-4 --stage denoiser --denoiser-from default [its DiT flags]  # your sensor
    torchrun --nproc-per-node 2 -m controltac_il.generator.train ...                 # data parallel (gloo, CPU)

Run folder (never the dataset folder)::

    train_config.json                      the arguments
    autoencoder_state.{safetensors,json}   autoencoder + AdamW + LR-schedule state, step (periodic, atomic)
    autoencoder_finetune_state.{...}       the same for a reused autoencoder's fine-tune (--ae-finetune-steps)
    latents.safetensors                    the dataset encoded once (the DiT trains on these)
    denoiser_state.{safetensors,json}      DiT + EMA + AdamW + LR-schedule state, step (periodic, atomic)
    final/                                 the inference checkpoint (fp16) + model_card.json

Stage 1 (autoencoder): L1 + MSE + image-gradient L1 on random crops of residuals in [-1, 1].
Stage 2 (DiT): pairs of the same contact pose; x0 = (z_target - z_ref) / delta_scale, noised by the
DDPM schedule; loss 0.5 L1 + 0.5 MSE on the noise (or on x0 for ``--prediction-type sample``);
AdamW, linear warm-up then cosine decay to ``min_lr_ratio`` of the peak (torch schedulers,
``controltac_il.training.lr_schedule``); EMA weights (diffusers' ``EMAModel``) are shipped.

The run folder is only written where it is new or holds this tool's own run: a previous run needs --resume
(continue) or --overwrite (replace: removes only the files listed above); files of the user's are never
replaced. A NaN / inf loss stops the run (exit 1) with the last saved state kept; Ctrl-C saves the current
step's state before exiting (exit 130). Bad options or data: one line on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from diffusers.training_utils import EMAModel
from safetensors.torch import load_file, save_file
from tqdm.auto import tqdm

from controltac_il.checkpoint import read_json
from controltac_il.config import one_line
from controltac_il.generator.autoencoder import TactileAutoencoder, autoencoder_loss
from controltac_il.generator.checkpoint import load_checkpoint, save_checkpoint
from controltac_il.generator.config import AutoencoderConfig, DiffusionConfig, GeneratorConfig
from controltac_il.generator.data import PairData, crop_batch, load_pair_data, sample_pairs
from controltac_il.generator.dit import ForceDiT
from controltac_il.generator.objectives import ema_weights, noised_batch, prediction_loss, restore_ema
from controltac_il.generator.pipeline import CHECKPOINT_ROOT, SHIPPED, residual_to_unit
from controltac_il.generator.sampler import make_scheduler
from controltac_il.generator.train_config import (DIT_PRESETS, STAGES, GeneratorTrainConfig, legacy_provenance, model_card,
                                                  provenance)
from controltac_il.io import atomic_path, write_json
from controltac_il.outputs import OutputInUse, claim_output, own_checkpoint, own_json, own_safetensors
from controltac_il.run_state import load_run_state, save_run_state
from controltac_il.training import barrier, lr_schedule, optimise, run_cli, setup_distributed, wrap

__all__ = ["GeneratorTrainConfig", "main", "parse_args", "run"]


# -- stage 1: autoencoder ----------------------------------------------------------------------

def fit_autoencoder(cfg: GeneratorTrainConfig, ae: TactileAutoencoder, data: PairData, out: Path, rank: int, world: int,
                    steps: int, state: str, stream: int, desc: str, extra: dict) -> dict:
    """AdamW on all of ``ae``'s weights for ``steps`` steps on random crops of ``data`` (the loss of
    ``autoencoder_loss``; crops drawn from the rng stream ``stream``), resumable from ``out/<state>``; ``extra``
    joins the saved state's metadata. Returns that metadata."""
    opt = torch.optim.AdamW(ae.parameters(), lr=cfg.ae_lr, weight_decay=0.0)
    stem = out / state
    meta = {"step": 0, "wall_s": 0.0}
    if stem.with_suffix(".json").is_file():
        meta, _ = load_run_state(stem, {"autoencoder": ae}, opt)
    sched = lr_schedule(opt, [cfg.ae_lr], steps, cfg.warmup_steps, cfg.min_lr_ratio * cfg.ae_lr,
                        meta.get("lr_schedule"), meta["step"])
    model, per_rank, t0 = wrap(ae, world), max(1, cfg.ae_batch // world), time.perf_counter()

    def batch_loss(step: int) -> torch.Tensor:
        x = crop_batch(data, np.random.default_rng([cfg.seed, stream, rank, step]), per_rank, cfg.ae_crop)
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
    zs = [ae.encode(residual_to_unit(torch.from_numpy(data.residuals[s:s + batch])))
          for s in tqdm(range(0, len(data.residuals), batch), desc="encoding dataset", unit="batch")]
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
        z = encode_all(ae, data)
        with atomic_path(path) as tmp:
            save_file({"latents": z.contiguous()}, str(tmp))
    barrier(world)
    z = load_file(str(path))["latents"]
    if z.shape[0] != len(data.residuals):
        raise ValueError(f"{path} holds {z.shape[0]} latents but the dataset has {len(data.residuals)} images; delete it")
    return z


# -- stage 2: DiT ------------------------------------------------------------------------------

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
    for part in ("dit", "autoencoder"):
        a, b = getattr(source, part).to_dict(), getattr(gcfg, part).to_dict()
        diff = {k: (a.get(k), b.get(k)) for k in a.keys() | b.keys() if a.get(k) != b.get(k)}
        if diff:
            raise ValueError(f"denoiser_from: {src} has another {part} config than this run "
                             f"(field: (source, this run)): {diff}")


def restore_denoiser(stem: Path, dit: ForceDiT, ema: EMAModel, opt: torch.optim.Optimizer | None = None) -> dict:
    """Load a denoiser state into ``dit``, ``ema`` (and ``opt``); returns its metadata. States written before the
    EMA's step count was recorded count one EMA update per step, as they were made."""
    meta, tensors = load_run_state(stem, {"denoiser": dit}, opt)
    restore_ema(ema, dit, tensors, meta.get("ema", {}).get("optimization_step", meta["step"]))
    return meta


def denoiser_loss(cfg: GeneratorTrainConfig, gcfg: GeneratorConfig, sched, z: torch.Tensor, data: PairData,
                  model: torch.nn.Module, rank: int, step: int, per_rank: int) -> torch.Tensor:
    """0.5 L1 + 0.5 MSE of the DiT's prediction (noise or x0) on one batch of same-pose latent pairs;
    ``sched``: the training noise schedule (diffusers)."""
    c = gcfg.autoencoder.latent_channels
    rng = np.random.default_rng([cfg.seed, 2, rank, step])
    ref, tgt, df = sample_pairs(data, per_rank, rng, cfg.no_contact_prob, cfg.distinct_pairs)
    x0 = (z[tgt] - z[ref]) / torch.tensor(gcfg.delta_scale).view(1, c, 1, 1)
    zr = z[ref] / torch.tensor(gcfg.latent_scale).view(1, c, 1, 1)
    x_t, t, target = noised_batch(gcfg, sched, x0, cfg.one_step_fraction, int(rng.integers(0, 2**62)))
    return prediction_loss(model(x_t, zr, t, torch.from_numpy(df)), target)


def train_denoiser(cfg: GeneratorTrainConfig, gcfg: GeneratorConfig, z: torch.Tensor, data: PairData, out: Path,
                   rank: int, world: int, init: dict[str, torch.Tensor] | None = None) -> tuple[ForceDiT, dict]:
    """Train (or resume) the DiT; ``init``: starting weights when there is no state to resume."""
    torch.manual_seed(cfg.seed + 1)
    dit = ForceDiT(gcfg.dit)
    if init is not None:
        dit.load_state_dict(init)
    ema = EMAModel(dit.parameters(), decay=cfg.ema_decay, update_after_step=-1)  # decay min(ema_decay, (1+n)/(10+n))
    opt = torch.optim.AdamW(dit.parameters(), lr=cfg.dit_lr, weight_decay=0.0)
    stem = out / "denoiser_state"
    meta = restore_denoiser(stem, dit, ema, opt) if stem.with_suffix(".json").is_file() else {"step": 0, "wall_s": 0.0}
    sched = lr_schedule(opt, [cfg.dit_lr], cfg.dit_steps, cfg.warmup_steps, cfg.min_lr_ratio * cfg.dit_lr,
                        meta.get("lr_schedule"), meta["step"])
    # one entry per (re)start: resumed runs may change the step budget or the prediction target
    history = meta.get("history", []) + [{"from_step": meta["step"], "dit_steps": cfg.dit_steps, "lr": cfg.dit_lr,
                                          "prediction_type": gcfg.diffusion.prediction_type, "batch": cfg.dit_batch,
                                          "one_step_fraction": cfg.one_step_fraction, "denoiser_from": cfg.denoiser_from}]
    model, per_rank, t0 = wrap(dit, world), max(1, cfg.dit_batch // world), time.perf_counter()
    noise_sched = make_scheduler(gcfg.diffusion)

    def save(step: int, loss: float) -> None:
        save_run_state(stem, {"denoiser": dit, "ema": ema_weights(ema, dit)},
                       {"step": step, "wall_s": meta["wall_s"] + time.perf_counter() - t0, "loss": loss,
                        "config": gcfg.to_dict(), "history": history, "ema": {"optimization_step": ema.optimization_step}},
                       opt, sched)

    optimise(meta["step"], cfg.dit_steps, lambda step: denoiser_loss(cfg, gcfg, noise_sched, z, data, model, rank, step, per_rank),
             opt, sched, list(dit.parameters()), save, cfg.checkpoint_every, f"denoiser ({cfg.dit_preset})", rank=rank,
             after_step=lambda step, out: ema.step(dit.parameters()), state=str(stem))
    barrier(world)
    if stem.with_suffix(".json").is_file():
        meta = restore_denoiser(stem, dit, ema)
    ema.copy_to(dit.parameters())
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
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "train_config.json", {**dataclasses.asdict(cfg), "world_size": world})
    barrier(world)
    t_start = time.perf_counter()
    data = load_pair_data(cfg.data, cfg.image_size, cfg.no_contact_frames, cfg.seed, progress=rank == 0)
    ae, ae_meta = autoencoder_for(cfg, data, out, rank, world)
    if cfg.stage == "autoencoder":
        return out

    z = cached_latents(cfg, ae, data, out, rank, world)
    source, init = (None, None) if cfg.denoiser_from is None else source_denoiser(Path(cfg.denoiser_from))
    lat, dsc = latent_scales(z, data, cfg.seed) if source is None else (source.latent_scale, source.delta_scale)
    gcfg = GeneratorConfig(
        autoencoder=ae.config,
        dit=DIT_PRESETS[cfg.dit_preset](in_channels=ae.config.latent_channels, patch_size=cfg.dit_patch,
                                        conv_head_width=cfg.dit_conv_head),
        diffusion=DiffusionConfig(prediction_type=cfg.prediction_type, default_steps=cfg.default_steps),
        latent_scale=lat, delta_scale=dsc, anchor_to_reference=cfg.anchor_to_reference, detail_gate=cfg.detail_gate,
    )
    if source is not None:
        check_same_models(Path(cfg.denoiser_from), source, gcfg)
    dit, dit_meta = train_denoiser(cfg, gcfg, z, data, out, rank, world, init)
    final = out / "final"
    if rank == 0:
        card = model_card(cfg, data, ae, ae_meta, dit, dit_meta, world, time.perf_counter() - t_start)
        save_checkpoint(final, gcfg, ae, dit, dtype=torch.float16, model_card=card)
        print(f"wrote {final}")
    barrier(world)
    if world > 1:
        dist.destroy_process_group()
    return final


def build_parser() -> argparse.ArgumentParser:
    d = GeneratorTrainConfig.__dataclass_fields__
    p = argparse.ArgumentParser(
        prog="python -m controltac_il.generator.train",
        description="Train the stage-1 force-control generator (autoencoder, then the ΔF-conditioned DiT on "
                    "cached latents) on a sensor-model dataset. Writes periodic resumable states and a final "
                    "fp16 checkpoint with a model card to OUT/final. Launch with torchrun for data parallelism (gloo, CPU).")
    p.add_argument("--data", required=True, help="dataset folder (controltac_il.tactile.dataset.write_dataset layout)")
    p.add_argument("--out", required=True, help="run folder for states, latents and OUT/final")
    p.add_argument("--stage", choices=STAGES, default="all", help="which stage(s) to train (default: all)")
    p.add_argument("--autoencoder-from", default=None,
                   help=f"reuse the autoencoder of this run or checkpoint folder, or of a shipped checkpoint ({', '.join(SHIPPED)})")
    p.add_argument("--denoiser-from", default=None,
                   help=f"start the DiT from this run or checkpoint folder's DiT, or a shipped one ({', '.join(SHIPPED)}): "
                        "fine-tuning, e.g. on your own sensor's presses; same architecture and autoencoder")
    p.add_argument("--resume", action="store_true", help="continue from the states in --out (without it, --out must not hold states)")
    p.add_argument("--image-size", type=int, nargs=2, default=d["image_size"].default, metavar=("H", "W"))
    p.add_argument("--ae-channels", type=int, nargs="+", default=d["ae_channels"].default, help="autoencoder stage widths")
    p.add_argument("--latent-channels", type=int, default=d["latent_channels"].default, help="autoencoder latent channels")
    p.add_argument("--dit-preset", choices=sorted(DIT_PRESETS), default="small", help="DiT size (default: small)")
    p.add_argument("--prediction-type", choices=("epsilon", "sample"), default="epsilon", help="what the DiT predicts")
    p.add_argument("--default-steps", type=int, default=d["default_steps"].default, help="DDIM steps stored as the default")
    p.add_argument("--dit-conv-head", type=int, default=0, metavar="WIDTH",
                   help="width of the DiT's local refinement head, 3x3 convs at latent resolution (default: 0 = none)")
    p.add_argument("--one-step-fraction", type=float, default=0.0, metavar="F",
                   help="share of each DiT batch trained at the last timestep, the one 1-step DDIM uses (default: 0)")
    p.add_argument("--ae-finetune-steps", type=int, default=0, metavar="N",
                   help="with --autoencoder-from: fine-tune that autoencoder N steps on --data (your sensor's look), "
                        "then the DiT on its moved latents (--denoiser-from with --dit-steps >= 1; default 0)")
    for name in ("dit_patch", "ae_steps", "ae_batch", "dit_steps", "dit_batch", "warmup_steps", "checkpoint_every", "seed",
                 "no_contact_frames", "threads"):
        p.add_argument("--" + name.replace("_", "-"), type=int, default=d[name].default)
    for name in ("ae_lr", "ae_contact_weight", "dit_lr", "min_lr_ratio", "ema_decay", "no_contact_prob"):
        p.add_argument("--" + name.replace("_", "-"), type=float, default=d[name].default)
    p.add_argument("--ae-crop", type=int, nargs=2, default=d["ae_crop"].default, metavar=("H", "W"))
    p.add_argument("--anchor-to-reference", action="store_true", help="output = reference + decoded change")
    p.add_argument("--distinct-pairs", action="store_true", help="never pair a frame with itself (no ΔF = 0 identity)")
    p.add_argument("--detail-gate", type=float, default=0.0, metavar="G",
                   help="with anchoring: keep the reference's fine detail only where the target keeps its contact; "
                        "G grey levels (default 0 = always keep; the shipped default uses 4)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a previous run in --out (only the files this tool wrote there; never anything else)")
    return p


def parse_args(argv=None) -> GeneratorTrainConfig:
    a = vars(build_parser().parse_args(argv))
    resume, overwrite = a.pop("resume"), a.pop("overwrite")
    for key in ("autoencoder_from", "denoiser_from"):  # a shipped checkpoint by name
        if a[key] in SHIPPED:
            a[key] = str(CHECKPOINT_ROOT / a[key])
    try:
        cfg = GeneratorTrainConfig(**a)
    except ValueError as exc:  # pydantic: one line naming the flag
        fail(one_line(exc, {f: "--" + f.replace("_", "-") for f in a}))
    if not Path(cfg.data).is_dir():
        fail(f"--data {cfg.data}: dataset folder not found (a controltac_il.tactile.dataset folder with manifest.csv)")
    out = Path(cfg.out)
    if out.resolve() == Path(cfg.data).resolve():
        fail(f"--out {out} is the dataset folder: choose a run folder of its own")
    if resume and overwrite:
        fail("--resume and --overwrite exclude each other: continue the run in --out, or replace it")
    has_state = any((out / f"{s}_state.json").is_file() for s in ("autoencoder", "autoencoder_finetune", "denoiser"))
    if resume and not has_state:
        fail(f"--resume: {out} holds no training state (autoencoder_, autoencoder_finetune_ or denoiser_state.json) to continue")
    rank0 = os.environ.get("RANK", "0") == "0"  # under torchrun only rank 0 removes a replaced run
    try:
        claim_output(out, RUN_OUTPUTS, resume=resume or (overwrite and not rank0), overwrite=overwrite,
                     tool="controltac_il.generator.train")
    except OutputInUse as exc:
        fail(str(exc))
    return cfg


def fail(message: str) -> None:
    """A bad option: one line on stderr, exit 2."""
    print(f"python -m controltac_il.generator.train: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def main(argv=None) -> int:
    """The CLI: 0 done, 1 stopped on a NaN / inf loss, 2 bad options or data (one line), 130 Ctrl-C (state saved)."""
    cfg = parse_args(argv)
    return run_cli("python -m controltac_il.generator.train", lambda: run(cfg))


# what a run writes in its folder, each with how it is recognised as this tool's own (--overwrite removes these)
RUN_OUTPUTS = {
    "train_config.json": own_json("data", "out", "stage"),
    "latents.safetensors": own_safetensors("latents"),
    "autoencoder_state.json": own_json("step", "config"),
    "autoencoder_state.safetensors": own_safetensors("autoencoder.", "optimizer."),
    "autoencoder_finetune_state.json": own_json("step", "trained_by"),
    "autoencoder_finetune_state.safetensors": own_safetensors("autoencoder.", "optimizer."),
    "denoiser_state.json": own_json("step", "config"),
    "denoiser_state.safetensors": own_safetensors("denoiser.", "ema.", "optimizer."),
    "final": own_checkpoint(("config.json", "autoencoder.safetensors", "denoiser.safetensors", "model_card.json"),
                            lambda c: "dit" in c and "autoencoder" in c),
}


if __name__ == "__main__":
    raise SystemExit(main())
