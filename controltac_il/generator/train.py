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
    denoiser_best.safetensors              with --val-objects: the EMA weights of the best validation step so far
    final/                                 the inference checkpoint (fp16) + model_card.json

Stage 1 (autoencoder): L1 + MSE + image-gradient L1 on random crops of residuals in [-1, 1].
Stage 2 (DiT): pairs of the same contact pose; x0 = (z_target - z_ref) / delta_scale, noised by the
DDPM schedule; loss 0.5 L1 + 0.5 MSE on the noise (or on x0 for ``--prediction-type sample``);
AdamW, linear warm-up then cosine decay to ``min_lr_ratio`` of the peak (torch schedulers,
``controltac_il.training.lr_schedule``); EMA weights (diffusers' ``EMAModel``) are shipped: with
``--val-objects N``, those of the periodic save with the lowest error on N held-out objects (the run's own
validation split; the benchmark's unseen objects and sensor are never looked at), else the last step's.

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

from controltac_il.cli import ArgumentParser
from controltac_il.config import one_line
from controltac_il.generator.shipped import CHECKPOINT_ROOT, SHIPPED
from controltac_il.generator.train_config import DIT_PRESETS, STAGES, GeneratorTrainConfig
from controltac_il.outputs import OutputInUse, claim_output, own_checkpoint, own_json, own_safetensors

__all__ = ["GeneratorTrainConfig", "main", "parse_args", "run"]


def run(cfg: GeneratorTrainConfig) -> Path:
    """Train per ``cfg``; returns the final checkpoint folder (``<out>/final``)."""
    import torch  # the job's imports: --help stays light (tests/test_cli_imports.py)
    import torch.distributed as dist

    from controltac_il.generator.checkpoint import save_checkpoint
    from controltac_il.generator.config import DiffusionConfig, GeneratorConfig
    from controltac_il.generator.data import load_pair_data
    from controltac_il.generator.pipeline import ForceGenerator
    from controltac_il.generator.stages import (autoencoder_for, cached_latents, check_same_models, latent_scales,
                                               source_denoiser, train_denoiser)
    from controltac_il.generator.train_config import model_card
    from controltac_il.generator.validation import Validation, generation_error, hold_out_objects
    from controltac_il.io import write_json
    from controltac_il.training import barrier, setup_distributed

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
    train_data, split = hold_out_objects(data, cfg.val_objects, cfg.seed)
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
    if source is not None:
        check_same_models(Path(cfg.denoiser_from), source, gcfg)
    validate = None if split is None else Validation(split.objects, len(split.ref), lambda d: generation_error(
        ForceGenerator(gcfg, ae, d, device=cfg.device), data.residuals[split.ref], data.residuals[split.tgt], split.delta))
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


def build_parser() -> argparse.ArgumentParser:
    d = GeneratorTrainConfig.__dataclass_fields__
    p = ArgumentParser(
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
    p.add_argument("--val-objects", type=int, default=0, metavar="N",
                   help="hold out N whole objects of --data as this run's validation split: their error is measured at "
                        "every --checkpoint-every and the best step is shipped (default 0 = the last step)")
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
    p.add_argument("--device", default="cpu",
                   help="where the networks train and the dataset is encoded: cpu (default) or cuda; pairs are drawn on the CPU")
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
    from controltac_il.training import device_problem

    problem = device_problem(cfg.device)
    if problem:
        fail(problem)
    if cfg.device != "cpu" and int(os.environ.get("WORLD_SIZE", "1")) > 1:
        fail(f"--device {cfg.device} under torchrun: data parallelism here is CPU only (gloo); train on one GPU instead")
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
    from controltac_il.training import run_cli

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
    "denoiser_best.safetensors": own_safetensors("best."),
    "final": own_checkpoint(("config.json", "autoencoder.safetensors", "denoiser.safetensors", "model_card.json"),
                            lambda c: "dit" in c and "autoencoder" in c),
}


if __name__ == "__main__":
    raise SystemExit(main())
