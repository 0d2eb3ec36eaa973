"""The generator's training command line: ``stage1`` trains the force-control generator, ``stage2`` the pose adapter.

    python -m controltac_il.generator.training stage1 --data DATASET --out RUN_DIR            # autoencoder, then DiT
    python -m controltac_il.generator.training stage1 --data DATASET --out RUN_DIR --resume   # continue
    python -m controltac_il.generator.training stage1 --data DATASET --out FAST_RUN --autoencoder-from RUN_DIR \
        --dit-preset tiny --prediction-type sample --default-steps 2                 # faster variant
    python -m controltac_il.generator.training stage1 --data NEW_DATASET --out TUNED --autoencoder-from RUN_DIR \
        --stage denoiser --denoiser-from RUN_DIR [same DiT flags] --dit-lr 3e-4       # fine-tune on new poses
    python -m controltac_il.generator.training stage1 --data MY_PRESSES --out TUNED --autoencoder-from default \
        --ae-finetune-steps 600 --ae-lr 2e-4 --stage denoiser --denoiser-from default [its DiT flags]   # your sensor
    torchrun --nproc-per-node 2 -m controltac_il.generator.training stage1 ...        # data parallel (gloo, CPU)
    python -m controltac_il.generator.training stage2 --out runs/pose            # pose adapter over the shipped default
    python -m controltac_il.generator.training stage2 --out runs/pose --resume   # continue

The jobs are ``stage1.run`` and ``stage2.run`` (their docstrings describe the run folders and the training); they
are imported only once the options hold, so ``--help`` loads no torch. A run folder is only written where it is
new or holds that subcommand's own run: a previous run needs --resume (continue) or --overwrite (replace: removes
only the files listed in ``STAGE1_OUTPUTS`` / ``STAGE2_OUTPUTS``); files of the user's are never replaced. A NaN /
inf loss stops the run (exit 1) with the last saved state kept; Ctrl-C saves the current step's state before
exiting (exit 130). Bad options or data: one line on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path

from controltac_il.cli import ArgumentParser
from controltac_il.config import one_line
from controltac_il.generator.shipped import CHECKPOINT_ROOT, SHIPPED, locate_checkpoint
from controltac_il.generator.training.config import (DIT_PRESETS, PROG, STAGE1_PROG, STAGE2_PROG, STAGES,
                                                     GeneratorTrainConfig, PoseTrainConfig)
from controltac_il.outputs import OutputInUse, claim_output, own_checkpoint, own_json, own_safetensors

__all__ = ["build_parser", "main", "parse_args"]

# what a run writes in its folder, each with how it is recognised as this tool's own (--overwrite removes these)
STAGE1_OUTPUTS = {
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
STAGE2_OUTPUTS = {
    "train_config.json": own_json("out", "base", "procedural"),
    "adapter_state.json": own_json("step", "config"),
    "adapter_state.safetensors": own_safetensors("adapter.", "ema.", "optimizer."),
    "adapter_best.safetensors": own_safetensors("best."),
    "final": own_checkpoint(("config.json", "adapter.safetensors", "model_card.json"), lambda c: "base" in c),
}


STAGE1_HELP = {
    "dit_patch": "latent pixels per DiT token side", "ae_steps": "autoencoder training steps",
    "ae_batch": "autoencoder batch (patches)", "dit_steps": "DiT training steps", "dit_batch": "DiT global batch (pairs)",
    "warmup_steps": "linear LR warm-up steps", "checkpoint_every": "steps between state saves (and validations)",
    "seed": "data order, noise, initialisation and the validation split", "no_contact_frames": "bare frames rendered",
    "threads": "torch threads per process", "ae_lr": "autoencoder peak learning rate",
    "ae_contact_weight": "extra autoencoder loss weight on contact pixels", "dit_lr": "DiT peak learning rate",
    "min_lr_ratio": "cosine decay floor, a fraction of the peak LR", "ema_decay": "EMA decay of the shipped DiT weights",
    "no_contact_prob": "share of no-contact pairs"}
STAGE2_HELP = {
    "procedural": "random training shapes besides the six training objects",
    "scenes": "scenes rendered per object", "poses": "contact poses per scene (>= 2: pairs cross poses)",
    "forces": "forces per pose", "size": "render size (pixels)", "instances": "training sensor instances drawn from",
    "steps": "training steps", "batch": "batch (pairs)", "lr": "peak learning rate", "warmup_steps": "linear warm-up steps",
    "min_lr_ratio": "cosine decay floor, a fraction of the peak LR", "ema_decay": "EMA decay of the shipped weights",
    "one_step_fraction": "share of each batch at the last timestep, the one 1-step DDIM uses",
    "mask_channels": "channels of the mask's latent features", "head_width": "the adapter's output head width",
    "alignment_px": "uniform noise (+-, pixels) shifting each training mask: a user's mask is never exact",
    "alignment_deg": "uniform noise (+-, degrees) rotating each training mask",
    "val_objects": "procedural shapes held out as the run's validation split (0: none, the last step ships)",
    "checkpoint_every": "steps between state saves (and validations)",
    "seed": "scenes, pairs, noise and initialisation", "threads": "torch threads (None: torch's default)",
    "device": "where the networks train: cpu or cuda (the data stays on the CPU)"}


def stage1_options(p: argparse.ArgumentParser) -> None:
    """The ``stage1`` subcommand's options (``GeneratorTrainConfig``'s fields plus --resume and --overwrite)."""
    d = GeneratorTrainConfig.__dataclass_fields__
    p.add_argument("--data", required=True, help="dataset folder (controltac_il.tactile.dataset.write_dataset layout)")
    p.add_argument("--out", required=True, help="run folder for states, latents and OUT/final")
    p.add_argument("--stage", choices=STAGES, default="all", help="which stage(s) to train (default: all)")
    p.add_argument("--autoencoder-from", default=None,
                   help=f"reuse the autoencoder of this run or checkpoint folder, or of a shipped checkpoint ({', '.join(SHIPPED)})")
    p.add_argument("--denoiser-from", default=None,
                   help=f"start the DiT from this run or checkpoint folder's DiT, or a shipped one ({', '.join(SHIPPED)}): "
                        "fine-tuning, e.g. on your own sensor's presses; same architecture and autoencoder")
    p.add_argument("--resume", action="store_true", help="continue from the states in --out (without it, --out must not hold states)")
    p.add_argument("--image-size", type=int, nargs=2, default=d["image_size"].default, metavar=("H", "W"),
                   help=f"the model's input size (pixels); dataset images are resized to it "
                        f"(default: {d['image_size'].default})")
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
        p.add_argument("--" + name.replace("_", "-"), type=int, default=d[name].default,
                       help=f"{STAGE1_HELP[name]} (default: {d[name].default})")
    for name in ("ae_lr", "ae_contact_weight", "dit_lr", "min_lr_ratio", "ema_decay", "no_contact_prob"):
        p.add_argument("--" + name.replace("_", "-"), type=float, default=d[name].default,
                       help=f"{STAGE1_HELP[name]} (default: {d[name].default})")
    p.add_argument("--ae-crop", type=int, nargs=2, default=d["ae_crop"].default, metavar=("H", "W"),
                   help=f"autoencoder training patch (pixels, within --image-size; default: {d['ae_crop'].default})")
    p.add_argument("--anchor-to-reference", action="store_true", help="output = reference + decoded change")
    p.add_argument("--distinct-pairs", action="store_true", help="never pair a frame with itself (no ΔF = 0 identity)")
    p.add_argument("--increase-prob", type=float, default=0.0, metavar="P",
                   help="share of pairs ordered to press harder (ΔFz >= 0), as ForceAugment's targets mostly do "
                        "(default 0: symmetric pairs)")
    p.add_argument("--new-contact-weight", type=float, default=0.0, metavar="W",
                   help="extra DiT loss weight on new contact, the target's contact beyond the reference's (default 0)")
    p.add_argument("--reference-force", action="store_true",
                   help="condition the DiT on the reference's own force too (where on its force response the contact "
                        "starts); from a --denoiser-from without it, training starts from that DiT's outputs")
    p.add_argument("--detail-gate", type=float, default=0.0, metavar="G",
                   help="with anchoring: keep the reference's fine detail only where the target keeps its contact; "
                        "G grey levels (default 0 = always keep; the shipped default uses 4)")
    p.add_argument("--device", default="cpu",
                   help="where the networks train and the dataset is encoded: cpu (default) or cuda; pairs are drawn on the CPU")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a previous run in --out (only the files this tool wrote there; never anything else)")


def stage2_options(p: argparse.ArgumentParser) -> None:
    """The ``stage2`` subcommand's options (``PoseTrainConfig``'s fields plus --resume and --overwrite)."""
    p.add_argument("--out", required=True, help="run folder (states, OUT/final)")
    p.add_argument("--base", default="default", help="frozen stage-1 checkpoint: a folder, or default / fast / quality (default: default)")
    p.add_argument("--adapter-from", default=None,
                   help="start from this adapter (a folder, or pose) instead of a zero-initialised one; same --base")
    p.add_argument("--resume", action="store_true", help="continue the run in --out")
    p.add_argument("--overwrite", action="store_true", help="replace a previous run in --out (only this tool's files)")
    for f in dataclasses.fields(PoseTrainConfig):
        if f.name in ("out", "base", "adapter_from"):
            continue
        default = f.default
        kw = {"nargs": 2, "type": int, "metavar": ("H", "W")} if f.name == "size" else {
            "type": float if isinstance(default, float) else str if isinstance(default, str) else int}
        p.add_argument("--" + f.name.replace("_", "-"), default=default, help=f"{STAGE2_HELP[f.name]} (default: {default})",
                       **kw)


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(prog=PROG, description="Train the generator: stage 1, the force-control generator, or stage 2, "
                                              "the pose adapter over a frozen stage 1.")
    sub = p.add_subparsers(dest="command", required=True, metavar="{stage1,stage2}")
    stage1_options(sub.add_parser(
        "stage1", prog=STAGE1_PROG, help="the force-control generator (autoencoder, then the ΔF-conditioned DiT)",
        description="Train the stage-1 force-control generator (autoencoder, then the ΔF-conditioned DiT on "
                    "cached latents) on a sensor-model dataset. Writes periodic resumable states and a final "
                    "fp16 checkpoint with a model card to OUT/final. Launch with torchrun for data parallelism (gloo, CPU)."))
    stage2_options(sub.add_parser(
        "stage2", prog=STAGE2_PROG, help="the pose adapter over a frozen stage-1 generator",
        description="Train the stage-2 pose adapter (contact mask at the target pose -> tactile image there) over a "
                    "frozen stage-1 generator on sensor-model scenes rendered in memory. Resumable states; the fp16 "
                    "adapter with its model card goes to OUT/final."))
    return p


def parse_args(argv=None) -> GeneratorTrainConfig | PoseTrainConfig:
    """The options of ``stage1`` or ``stage2`` (the first argument) as that stage's config, its run folder claimed;
    bad options: one line on stderr and SystemExit(2)."""
    a = vars(build_parser().parse_args(argv))
    return stage1_config(a) if a.pop("command") == "stage1" else stage2_config(a)


def stage1_config(a: dict) -> GeneratorTrainConfig:
    resume, overwrite = a.pop("resume"), a.pop("overwrite")
    for key in ("autoencoder_from", "denoiser_from"):  # a shipped checkpoint by name
        if a[key] in SHIPPED:
            a[key] = str(CHECKPOINT_ROOT / a[key])
    try:
        cfg = GeneratorTrainConfig(**a)
    except ValueError as exc:  # pydantic: one line naming the flag
        fail(STAGE1_PROG, one_line(exc, {f: "--" + f.replace("_", "-") for f in a}))
    check_device(STAGE1_PROG, cfg.device)
    if cfg.device != "cpu" and int(os.environ.get("WORLD_SIZE", "1")) > 1:
        fail(STAGE1_PROG, f"--device {cfg.device} under torchrun: data parallelism here is CPU only (gloo); train on one GPU instead")
    if not Path(cfg.data).is_dir():
        fail(STAGE1_PROG, f"--data {cfg.data}: dataset folder not found (a controltac_il.tactile.dataset folder with manifest.csv)")
    for flag, source in (("--autoencoder-from", cfg.autoencoder_from), ("--denoiser-from", cfg.denoiser_from)):
        if source is not None and not Path(source).is_dir():  # checked now, not after hours of training
            fail(STAGE1_PROG, f"{flag} {source}: no such checkpoint folder (a folder, or one of {', '.join(SHIPPED)})")
    out = Path(cfg.out)
    if out.resolve() == Path(cfg.data).resolve():
        fail(STAGE1_PROG, f"--out {out} is the dataset folder: choose a run folder of its own")
    if resume and overwrite:
        fail(STAGE1_PROG, "--resume and --overwrite exclude each other: continue the run in --out, or replace it")
    has_state = any((out / f"{s}_state.json").is_file() for s in ("autoencoder", "autoencoder_finetune", "denoiser"))
    if resume and not has_state:
        fail(STAGE1_PROG, f"--resume: {out} holds no training state (autoencoder_, autoencoder_finetune_ or denoiser_state.json) to continue")
    rank0 = os.environ.get("RANK", "0") == "0"  # under torchrun only rank 0 removes a replaced run
    try:
        claim_output(out, STAGE1_OUTPUTS, resume=resume or (overwrite and not rank0), overwrite=overwrite, tool=STAGE1_PROG)
    except (OutputInUse, OSError) as exc:  # in use, or unreadable / not removable
        fail(STAGE1_PROG, one_line(exc))
    return cfg


def stage2_config(a: dict) -> PoseTrainConfig:
    resume, overwrite = a.pop("resume"), a.pop("overwrite")
    try:
        cfg = PoseTrainConfig(**a)
    except ValueError as exc:
        fail(STAGE2_PROG, one_line(exc, {f: "--" + f.replace("_", "-") for f in a}))
    try:
        locate_checkpoint(cfg.base)
    except FileNotFoundError as exc:
        fail(STAGE2_PROG, f"--base: {exc}")
    check_device(STAGE2_PROG, cfg.device)
    if resume and overwrite:
        fail(STAGE2_PROG, "--resume and --overwrite exclude each other")
    if resume and not (Path(cfg.out) / "adapter_state.json").is_file():
        fail(STAGE2_PROG, f"--resume: {cfg.out} holds no adapter_state.json to continue")
    try:
        claim_output(cfg.out, STAGE2_OUTPUTS, resume=resume, overwrite=overwrite, tool=STAGE2_PROG)
    except (OutputInUse, OSError) as exc:  # in use, or unreadable / not removable
        fail(STAGE2_PROG, one_line(exc))
    return cfg


def check_device(prog: str, device: str) -> None:
    from controltac_il.training import device_problem

    problem = device_problem(device)
    if problem:
        fail(prog, problem)


def fail(prog: str, message: str) -> None:
    """A bad option: one line on stderr, exit 2."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def train(cfg: GeneratorTrainConfig | PoseTrainConfig):
    """Run ``cfg``'s stage (its job imported here: the heavy imports); returns its final checkpoint folder."""
    if isinstance(cfg, PoseTrainConfig):
        from controltac_il.generator.training.stage2 import run
    else:
        from controltac_il.generator.training.stage1 import run
    return run(cfg)


def main(argv=None) -> int:
    """The CLI: 0 done, 1 stopped on a NaN / inf loss, 2 bad options or data (one line), 130 Ctrl-C (state saved)."""
    cfg = parse_args(argv)
    from controltac_il.training import run_cli

    return run_cli(STAGE2_PROG if isinstance(cfg, PoseTrainConfig) else STAGE1_PROG, lambda: train(cfg))
