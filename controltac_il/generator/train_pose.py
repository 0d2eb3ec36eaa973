"""Train the stage-2 pose adapter over a frozen stage-1 generator on sensor-model scenes.

    python -m controltac_il.generator.train_pose --out runs/pose                 # adapter over the shipped default
    python -m controltac_il.generator.train_pose --out runs/pose --resume        # continue

Data: ``pose_data.render_scenes`` (the six training objects plus ``--procedural`` random shapes, each in
``--scenes`` scenes on random training sensor instances, ``--poses`` x ``--forces`` frames per scene), rendered
in memory and encoded once by the frozen autoencoder. Pairs within a scene; the condition is the reference's
contact mask carried to the target pose with the paper's alignment noise (±3 px, ±1°). Loss as stage 1's
(0.5 L1 + 0.5 MSE on the normalised latent change, ``--one-step-fraction`` at the last timestep); AdamW with
warm-up and cosine decay; the EMA of the adapter is shipped (fp16, ``OUT/final``): that of the state save with
the lowest error on ``--val-objects`` procedural shapes it never trains on (its own validation split; the
benchmark's held-out objects are never looked at). The stage-1 weights are never changed.

The job is ``pose_training.run``. Run folder: ``train_config.json``, ``adapter_state.{safetensors,json}`` (periodic, atomic), ``adapter_best.safetensors``
(the best validation step's EMA weights), ``final/``. ``--resume``
continues with the saved run's data and model (only ``--steps``, ``--checkpoint-every``, ``--threads``, ``--device``
may change; anything else, or another ``--base``, is refused).
Only this tool's own files there are ever replaced (``--overwrite``); bad options: one line, exit 2; a NaN / inf
loss: exit 1 with the last state kept; Ctrl-C: the step's state saved, exit 130.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

from controltac_il.cli import ArgumentParser
from controltac_il.config import one_line
from controltac_il.generator.shipped import locate_checkpoint
from controltac_il.generator.train_config import POSE_PROG as PROG, PoseTrainConfig
from controltac_il.outputs import OutputInUse, claim_output, own_checkpoint, own_json, own_safetensors

RUN_OUTPUTS = {
    "train_config.json": own_json("out", "base", "procedural"),
    "adapter_state.json": own_json("step", "config"),
    "adapter_state.safetensors": own_safetensors("adapter.", "ema.", "optimizer."),
    "adapter_best.safetensors": own_safetensors("best."),
    "final": own_checkpoint(("config.json", "adapter.safetensors", "model_card.json"), lambda c: "base" in c),
}


def fail(message: str) -> None:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def parse_args(argv=None) -> PoseTrainConfig:
    fields = {f.name: f for f in dataclasses.fields(PoseTrainConfig)}
    p = ArgumentParser(prog=PROG, description=(
        "Train the stage-2 pose adapter (contact mask at the target pose -> tactile image there) over a frozen "
        "stage-1 generator on sensor-model scenes rendered in memory. Resumable states; the fp16 adapter with its "
        "model card goes to OUT/final."))
    p.add_argument("--out", required=True, help="run folder (states, OUT/final)")
    p.add_argument("--base", default="default", help="frozen stage-1 checkpoint: a folder, or default / fast / quality (default: default)")
    p.add_argument("--adapter-from", default=None,
                   help="start from this adapter (a folder, or pose) instead of a zero-initialised one; same --base")
    p.add_argument("--resume", action="store_true", help="continue the run in --out")
    p.add_argument("--overwrite", action="store_true", help="replace a previous run in --out (only this tool's files)")
    for name, f in fields.items():
        if name in ("out", "base", "adapter_from"):
            continue
        default = f.default
        kw = {"nargs": 2, "type": int, "metavar": ("H", "W")} if name == "size" else {
            "type": float if isinstance(default, float) else str if isinstance(default, str) else int}
        p.add_argument("--" + name.replace("_", "-"), default=default, help=f"(default: {default})", **kw)
    a = vars(p.parse_args(argv))
    resume, overwrite = a.pop("resume"), a.pop("overwrite")
    try:
        cfg = PoseTrainConfig(**a)
    except ValueError as exc:
        fail(one_line(exc, {f: "--" + f.replace("_", "-") for f in a}))
    try:
        locate_checkpoint(cfg.base)
    except FileNotFoundError as exc:
        fail(f"--base: {exc}")
    from controltac_il.training import device_problem

    problem = device_problem(cfg.device)
    if problem:
        fail(problem)
    if resume and overwrite:
        fail("--resume and --overwrite exclude each other")
    if resume and not (Path(cfg.out) / "adapter_state.json").is_file():
        fail(f"--resume: {cfg.out} holds no adapter_state.json to continue")
    try:
        claim_output(cfg.out, RUN_OUTPUTS, resume=resume, overwrite=overwrite, tool=PROG)
    except OutputInUse as exc:
        fail(str(exc))
    return cfg


def main(argv=None) -> int:
    """The CLI: 0 done, 1 NaN / inf loss, 2 bad options (one line), 130 Ctrl-C (state saved)."""
    cfg = parse_args(argv)
    from controltac_il.generator.pose_training import run
    from controltac_il.training import run_cli

    return run_cli(PROG, lambda: run(cfg))


if __name__ == "__main__":
    raise SystemExit(main())
