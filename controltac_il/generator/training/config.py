"""Arguments of a generator training run and the provenance it records.

``GeneratorTrainConfig`` (stage 1) and ``PoseTrainConfig`` (the stage-2 adapter) are pydantic dataclasses saved as a
run's ``train_config.json``; a stage-1 run also records the command that reproduces it, its dataset and its model
card."""

from __future__ import annotations

import dataclasses
import json
import os
import platform
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import Field, model_validator
from pydantic.dataclasses import dataclass

from controltac_il.checkpoint import read_json
from controltac_il.config import PosInt, Positive, STRICT, one_line_errors
from controltac_il.generator.config import AutoencoderConfig, DiffusionConfig, DiTConfig
from controltac_il.generator.forces import VALIDATED_RANGE

if TYPE_CHECKING:
    from controltac_il.generator.autoencoder import TactileAutoencoder
    from controltac_il.generator.training.data import PairData
    from controltac_il.generator.dit import ForceDiT

PROG = "python -m controltac_il.generator.training"
STAGE1_PROG, STAGE2_PROG = PROG + " stage1", PROG + " stage2"
DIT_PRESETS = {"small": DiTConfig.small, "tiny": DiTConfig.tiny, "base": DiTConfig.base}
STAGES = ("all", "autoencoder", "denoiser")
Count = Annotated[int, Field(ge=0)]
Share = Annotated[float, Field(ge=0, lt=1)]


@one_line_errors
@dataclass(config=STRICT)
class GeneratorTrainConfig:
    """Arguments of one stage-1 training run.

    data: dataset folder written by ``controltac_il.tactile.dataset.write_dataset``.
    out: run folder (states, latents, final checkpoint).
    stage: "all", "autoencoder" or "denoiser" (the latter needs a trained autoencoder).
    autoencoder_from: run folder or checkpoint whose trained autoencoder is reused (skips stage 1).
    denoiser_from: run folder or checkpoint whose DiT (EMA weights) starts this run's DiT: fine-tuning,
        e.g. on freshly rendered poses. Its DiT architecture and autoencoder config must match this
        run's, and its latent and ΔF scales are kept (the weights were trained on them). The model
        card's ``denoiser.lineage`` lists the source's own trainings, so a chain of fine-tunes stays
        reproducible.
    image_size: (H, W) of the model; dataset images are resized to it.
    ae_channels, latent_channels: autoencoder stage widths (f = 2**len) and latent channels.
    dit_preset: "small" (default teacher), "tiny" (faster variant) or "base"; dit_patch: latent pixels per token side.
    dit_conv_head: width of the DiT's local refinement head (0 = none; see DiTConfig.conv_head_width).
    prediction_type: "epsilon" (paper) or "sample"; default_steps: DDIM steps stored as the default.
    ae_steps, ae_batch, ae_lr, ae_crop: autoencoder optimisation (crop (H, W) of the training patches, within image_size).
    ae_contact_weight: extra loss weight on contact pixels of the autoencoder's targets.
    ae_finetune_steps: with ``autoencoder_from``, fine-tune the reused autoencoder (encoder and decoder) for this
        many steps on ``data`` (batch ``ae_batch``, peak LR ``ae_lr``, crops ``ae_crop``): a new sensor's look.
        Its latent space moves, so the DiT must train after it (``dit_steps`` >= 1). 0 = reuse it unchanged.
    dit_steps, dit_batch, dit_lr: DiT optimisation (global batch, split across processes). 0 DiT steps only
        with ``denoiser_from`` (a copy of that DiT); 0 autoencoder steps only where the autoencoder is reused.
    one_step_fraction: share of each DiT batch drawn at the last training timestep (the only one a
        1-step DDIM sampler visits); the rest is uniform over all timesteps, as in the paper.
    min_lr_ratio: cosine decay floor as a fraction of the peak LR; warmup_steps: linear warm-up.
    ema_decay: EMA of the DiT weights (the shipped weights).
    no_contact_prob: share of no-contact pairs; no_contact_frames: how many bare frames to render.
    increase_prob: share of pairs ordered so that the target presses harder than the reference (ΔFz >= 0), as most
        ForceAugment targets do; 0 keeps the pairs symmetric. new_contact_weight: extra loss weight on latent cells of
        new contact (the target's contact beyond the reference's; 0 = none). reference_force: the DiT is also
        conditioned on the reference's own force (``DiTConfig.reference_force``); from a ``denoiser_from`` without
        it, its new embedder starts at zero, so training starts from that DiT's very outputs.
    distinct_pairs: never pair a frame with itself (ΔF = 0 exactly); by default 1 / forces-per-pose of the pairs
        are self-pairs, which teach the identity at ΔF = 0 apart from the response next to it.
    anchor_to_reference, detail_gate: inference settings stored in the config (see GeneratorConfig).
    val_objects: whole objects of ``data`` held out as this run's validation split (drawn by ``seed``): the DiT's
        error on their pairs is measured at every periodic save and the step with the lowest one is shipped
        (0 = no split: the last step is shipped).
    checkpoint_every: steps between periodic state saves. seed: data order, noise, init, the split.
    threads: torch intra-op threads per process (None = torch's default).
    device: where the networks train and the dataset is encoded ("cpu", "cuda"); pairs are drawn on the CPU.
    """

    data: str
    out: str
    stage: Literal["all", "autoencoder", "denoiser"] = "all"
    autoencoder_from: str | None = None
    denoiser_from: str | None = None
    image_size: tuple[PosInt, PosInt] = (128, 160)
    ae_channels: Annotated[tuple[PosInt, ...], Field(min_length=1)] = (16, 48, 96)
    latent_channels: PosInt = 8
    dit_preset: Literal["small", "tiny", "base"] = "small"
    dit_patch: PosInt = 2
    dit_conv_head: Count = 0
    prediction_type: Literal["epsilon", "sample"] = "epsilon"
    default_steps: PosInt = 10
    ae_steps: Count = 1500
    ae_batch: PosInt = 32
    ae_lr: Positive = 2e-3
    ae_crop: tuple[PosInt, PosInt] = (64, 80)
    ae_contact_weight: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 4.0
    ae_finetune_steps: Count = 0
    dit_steps: Count = 4000
    dit_batch: PosInt = 128
    dit_lr: Positive = 5e-4
    one_step_fraction: Annotated[float, Field(ge=0, le=1)] = 0.0
    min_lr_ratio: Annotated[float, Field(gt=0, le=1)] = 0.1
    warmup_steps: Count = 100
    ema_decay: Share = 0.999
    no_contact_prob: Share = 0.05
    no_contact_frames: Count = 32
    distinct_pairs: bool = False
    increase_prob: Share = 0.0
    new_contact_weight: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.0
    reference_force: bool = False
    anchor_to_reference: bool = False
    detail_gate: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.0
    val_objects: Count = 0
    checkpoint_every: PosInt = 250
    seed: Annotated[int, Field(ge=0)] = 0  # numpy's generators take no negative seed
    threads: PosInt | None = None
    device: str = "cpu"

    @model_validator(mode="after")
    def _consistent(self):
        AutoencoderConfig(image_size=self.image_size, channels=self.ae_channels, latent_channels=self.latent_channels)
        DiffusionConfig(prediction_type=self.prediction_type, default_steps=self.default_steps)
        if self.detail_gate > 0 and not self.anchor_to_reference:
            raise ValueError(f"detail_gate={self.detail_gate} needs --anchor-to-reference")
        if any(c > s for c, s in zip(self.ae_crop, self.image_size)):
            raise ValueError(f"ae_crop {self.ae_crop} must fit in image_size {self.image_size}")
        if self.dit_steps == 0 and self.stage != "autoencoder" and self.denoiser_from is None:
            raise ValueError("dit_steps=0 (--dit-steps) would ship an untrained DiT: give it >= 1 steps, or start it "
                             "from --denoiser-from (0 steps then copies that DiT)")
        if self.ae_steps == 0 and self.stage != "denoiser" and self.autoencoder_from is None:
            raise ValueError("ae_steps=0 (--ae-steps) would leave the autoencoder untrained: give it >= 1 steps, or "
                             "reuse one with --autoencoder-from")
        if self.ae_finetune_steps and self.autoencoder_from is None:
            raise ValueError(f"ae_finetune_steps={self.ae_finetune_steps} fine-tunes a reused autoencoder: give --autoencoder-from")
        if self.ae_finetune_steps and self.dit_steps == 0 and self.stage != "autoencoder":
            raise ValueError("ae_finetune_steps moves the latent space: a DiT copied with dit_steps=0 (--dit-steps) would "
                             "no longer match it; give --dit-steps >= 1")
        if self.stage == "denoiser" and self.autoencoder_from is None and not (Path(self.out) / "autoencoder_state.json").is_file():
            raise ValueError("stage 'denoiser' needs --autoencoder-from or a trained autoencoder in --out")
        return self


def cli_args(cfg: GeneratorTrainConfig) -> list[str]:
    """The command-line arguments that reproduce ``cfg`` (defaults and ``threads`` left out)."""
    args = []
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if v == f.default or v is None or (f.name == "threads"):
            continue
        flag = "--" + f.name.replace("_", "-")
        if isinstance(v, bool):
            args.append(flag)
        elif isinstance(v, tuple):
            args += [flag, *map(str, v)]
        else:
            args += [flag, str(v)]
    return args


def provenance(cfg: GeneratorTrainConfig) -> dict:
    """The command that reproduces ``cfg`` and its dataset (path, seed, image count from its meta.json)."""
    meta_path = Path(cfg.data) / "meta.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    return {"command": STAGE1_PROG + " " + " ".join(cli_args(cfg)),
            "data": {"path": str(cfg.data), "seed": meta.get("seed"), "images": meta.get("count")}}


def legacy_provenance(run: Path) -> dict | None:
    """``provenance`` rebuilt from a run folder's ``train_config.json`` (its latest invocation's arguments;
    None without one). Fields added to GeneratorTrainConfig since take their defaults."""
    path = run / "train_config.json"
    if not path.is_file():
        return None
    saved = json.loads(path.read_text())
    return provenance(GeneratorTrainConfig(**{f.name: saved[f.name] for f in dataclasses.fields(GeneratorTrainConfig) if f.name in saved}))


def denoiser_lineage(src: Path) -> list[dict]:
    """The trainings a ``--denoiser-from`` source went through, oldest first: its model card's lineage plus its
    own command, data, steps and wall time. Read from a checkpoint's card, or from a run folder's ``final/``
    card when that holds the run's latest state; empty where no card says (a run stopped mid-way)."""
    card_path = src / "model_card.json"
    if not card_path.is_file():
        card_path = src / "final" / "model_card.json"
        state = src / "denoiser_state.json"
        if not card_path.is_file() or (state.is_file() and read_json(state)["step"]
                                       != read_json(card_path)["denoiser"]["steps"]):
            return []
    card = read_json(card_path)
    d, data = card.get("denoiser", {}), card.get("data", {})
    return d.get("lineage", []) + [{"command": card.get("command"), "data": {k: data.get(k) for k in ("path", "seed", "images")},
                                    "steps": d.get("steps"), "wall_s": d.get("wall_s")}]


def model_card(cfg: GeneratorTrainConfig, data: PairData, ae: TactileAutoencoder, ae_meta: dict, dit: ForceDiT, dit_meta: dict,
               world: int, wall_s: float) -> dict:
    """The final checkpoint's ``model_card.json``: command, data, each stage's cost and lineage, machine."""
    import torch

    from controltac_il.training import device_name

    meta = read_json(Path(cfg.data) / "meta.json") if (Path(cfg.data) / "meta.json").is_file() else {}
    return {
        "model": "controltac-il stage-1 force-control generator (tactile autoencoder + ΔF-conditioned DiT + DDIM)",
        "command": STAGE1_PROG + " " + " ".join(cli_args(cfg)),
        "data": {"path": str(cfg.data), "seed": meta.get("seed"), "objects": meta.get("objects"),
                 "images": int(len(data.residuals) - len(data.no_contact)), "pose_groups": len(data.groups),
                 "no_contact_frames": int(len(data.no_contact)), "fz_range": meta.get("fz_range"),
                 "optics": meta.get("optics"), "render_size": [meta.get("spec", {}).get("height"), meta.get("spec", {}).get("width")]},
        "autoencoder": {"steps": ae_meta.get("step"), "wall_s": ae_meta.get("wall_s"), "final_loss": ae_meta.get("loss"),
                        "from": ae_meta.get("from"), "trained_by": ae_meta.get("trained_by"),
                        **({"finetune": ae_meta["finetune"]} if "finetune" in ae_meta else {})},
        "denoiser": {"preset": cfg.dit_preset, "steps": dit_meta["step"], "wall_s": dit_meta["wall_s"],
                     "final_loss": dit_meta.get("loss"), "from": cfg.denoiser_from, "batch": cfg.dit_batch, "lr": cfg.dit_lr,
                     "lineage": [] if cfg.denoiser_from is None else denoiser_lineage(Path(cfg.denoiser_from)),
                     "parameters": sum(p.numel() for p in dit.parameters()), "history": dit_meta.get("history"),
                     "validation": dit_meta.get("validation")},
        "autoencoder_parameters": sum(p.numel() for p in ae.parameters()),
        "world_size": world,
        "total_wall_s": wall_s,
        "machine": {"cpu_count": os.cpu_count(), "torch": torch.__version__, "python": platform.python_version(),
                    "device": device_name(cfg.device)},
        "weights_dtype": "float16",
        "validated_range": VALIDATED_RANGE.card(),
    }


@one_line_errors
@dataclass(config=STRICT)
class PoseTrainConfig:
    """Arguments of one adapter training run.

    out: run folder. base: the frozen stage-1 checkpoint (a folder, or "default" / "fast"). adapter_from: start from
    this adapter (a folder, or "pose") instead of the zero-initialised one: a longer or a fine-tuning run; it must
    have been trained over ``base``, with the same widths.
    procedural: random training shapes besides the six training objects. scenes, poses, forces: scenes per object,
    contact poses per scene, forces per pose (render size ``size`` (H, W)); instances: training sensor instances
    drawn from. steps, batch, lr, warmup_steps, min_lr_ratio, ema_decay: optimisation. one_step_fraction: share of
    each batch at the last timestep. mask_channels, head_width, alignment_px, alignment_deg: PoseAdapterConfig.
    val_objects: procedural shapes after the training ones (``procedural_<procedural>`` on), never trained on, in
    two scenes each: the run's own validation split. The adapter's error on their cross-pose pairs is measured at
    every state save and the best step's EMA weights ship (0 = no split: the last step ships).
    checkpoint_every: steps between state saves. seed: scenes, pairs, noise, init. threads: torch threads (None =
    torch's default). device: where the networks train ("cpu", "cuda"); the data stays on the CPU.
    """

    out: str
    base: str = "default"
    adapter_from: str | None = None
    procedural: Annotated[int, Field(ge=0)] = 120
    scenes: PosInt = 6
    poses: Annotated[int, Field(ge=2)] = 4
    forces: PosInt = 3
    size: tuple[PosInt, PosInt] = (120, 160)
    instances: PosInt = 16
    steps: PosInt = 6000
    batch: PosInt = 64
    lr: Positive = 3e-4
    warmup_steps: Annotated[int, Field(ge=0)] = 200
    min_lr_ratio: Annotated[float, Field(ge=0, le=1)] = 0.05
    ema_decay: Annotated[float, Field(ge=0, lt=1)] = 0.999
    one_step_fraction: Annotated[float, Field(ge=0, le=1)] = 0.9
    mask_channels: PosInt = 32
    head_width: PosInt = 48
    alignment_px: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 3.0
    alignment_deg: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 1.0
    val_objects: Annotated[int, Field(ge=0)] = 8
    checkpoint_every: PosInt = 500
    seed: Annotated[int, Field(ge=0)] = 0
    threads: PosInt | None = None
    device: str = "cpu"


# what a resumed run may change (the step budget, how it runs); anything else must match the saved run
RESUMABLE_CHANGES = ("steps", "checkpoint_every", "threads", "device")
