"""Train the force-control generator: autoencoder first, then the DiT on cached latents.

    python -m controltac_il.generator.train --data DATASET --out RUN_DIR            # both stages
    python -m controltac_il.generator.train --data DATASET --out RUN_DIR --resume   # continue
    python -m controltac_il.generator.train --data DATASET --out FAST_RUN --autoencoder-from RUN_DIR \
        --dit-preset tiny --prediction-type sample --default-steps 2                  # faster variant
    python -m controltac_il.generator.train --data NEW_DATASET --out TUNED --autoencoder-from RUN_DIR \
        --stage denoiser --denoiser-from RUN_DIR [same DiT flags] --dit-lr 3e-4        # fine-tune on new poses
    torchrun --nproc-per-node 2 -m controltac_il.generator.train ...                 # data parallel (gloo, CPU)

Run folder (never the dataset folder)::

    train_config.json                      the arguments
    autoencoder_state.{safetensors,json}   autoencoder + AdamW state, step (periodic, atomic)
    latents.safetensors                    the dataset encoded once (the DiT trains on these)
    denoiser_state.{safetensors,json}      DiT + EMA + AdamW state, step (periodic, atomic)
    final/                                 the inference checkpoint (fp16) + model_card.json

Stage 1 (autoencoder): L1 + MSE + image-gradient L1 on random crops of residuals in [-1, 1].
Stage 2 (DiT): pairs of the same contact pose; x0 = (z_target - z_ref) / delta_scale, noised by the
DDPM schedule; loss 0.5 L1 + 0.5 MSE on the noise (or on x0 for ``--prediction-type sample``);
AdamW, linear warm-up then cosine decay to ``min_lr_ratio`` of the peak; EMA weights are shipped.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from safetensors.torch import load_file, save_file
from torch.nn import functional as F
from tqdm.auto import tqdm

from controltac_il.generator.autoencoder import TactileAutoencoder
from controltac_il.generator.checkpoint import load_checkpoint, save_checkpoint
from controltac_il.generator.config import AutoencoderConfig, DiffusionConfig, DiTConfig, GeneratorConfig
from controltac_il.generator.data import PairData, load_pair_data, sample_pairs
from controltac_il.generator.dit import ForceDiT
from controltac_il.tactile.residual import contact_mask
from controltac_il.generator.pipeline import residual_to_unit
from controltac_il.generator.sampler import make_scheduler
from controltac_il.io import atomic_path, write_json

DIT_PRESETS = {"small": DiTConfig.small, "tiny": DiTConfig.tiny, "base": DiTConfig.base}
STAGES = ("all", "autoencoder", "denoiser")


@dataclass
class TrainConfig:
    """Arguments of one training run.

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
    ae_steps, ae_batch, ae_lr, ae_crop: autoencoder optimisation (crop (H, W) of the training patches).
    ae_contact_weight: extra loss weight on contact pixels of the autoencoder's targets.
    dit_steps, dit_batch, dit_lr: DiT optimisation (global batch, split across processes).
    one_step_fraction: share of each DiT batch drawn at the last training timestep (the only one a
        1-step DDIM sampler visits); the rest is uniform over all timesteps, as in the paper.
    min_lr_ratio: cosine decay floor as a fraction of the peak LR; warmup_steps: linear warm-up.
    ema_decay: EMA of the DiT weights (the shipped weights).
    no_contact_prob: share of no-contact pairs; no_contact_frames: how many bare frames to render.
    anchor_to_reference, detail_gate: inference settings stored in the config (see GeneratorConfig).
    checkpoint_every: steps between periodic state saves. seed: data order, noise, init.
    threads: torch intra-op threads per process (None = torch's default).
    """

    data: str
    out: str
    stage: str = "all"
    autoencoder_from: str | None = None
    denoiser_from: str | None = None
    image_size: tuple[int, int] = (128, 160)
    ae_channels: tuple[int, ...] = (16, 48, 96)
    latent_channels: int = 8
    dit_preset: str = "small"
    dit_patch: int = 2
    dit_conv_head: int = 0
    prediction_type: str = "epsilon"
    default_steps: int = 10
    ae_steps: int = 1500
    ae_batch: int = 32
    ae_lr: float = 2e-3
    ae_crop: tuple[int, int] = (64, 80)
    ae_contact_weight: float = 4.0
    dit_steps: int = 4000
    dit_batch: int = 128
    dit_lr: float = 5e-4
    one_step_fraction: float = 0.0
    min_lr_ratio: float = 0.1
    warmup_steps: int = 100
    ema_decay: float = 0.999
    no_contact_prob: float = 0.05
    no_contact_frames: int = 32
    anchor_to_reference: bool = False
    detail_gate: float = 0.0
    checkpoint_every: int = 250
    seed: int = 0
    threads: int | None = None

    def __post_init__(self):
        self.image_size = tuple(self.image_size)
        self.ae_crop = tuple(self.ae_crop)
        self.ae_channels = tuple(self.ae_channels)
        AutoencoderConfig(image_size=self.image_size, channels=self.ae_channels, latent_channels=self.latent_channels)
        if self.stage not in STAGES:
            raise ValueError(f"stage must be one of {STAGES}, got {self.stage!r}")
        if self.dit_preset not in DIT_PRESETS:
            raise ValueError(f"dit_preset must be one of {sorted(DIT_PRESETS)}, got {self.dit_preset!r}")
        DiffusionConfig(prediction_type=self.prediction_type, default_steps=self.default_steps)
        for n in ("ae_steps", "dit_steps"):
            v = getattr(self, n)
            if not isinstance(v, int) or v < 0:
                raise ValueError(f"{n} must be an int >= 0, got {v!r}")
        for n in ("ae_batch", "dit_batch", "checkpoint_every", "no_contact_frames", "dit_conv_head"):
            v = getattr(self, n)
            low = 0 if n in ("no_contact_frames", "dit_conv_head") else 1
            if not isinstance(v, int) or isinstance(v, bool) or v < low:
                raise ValueError(f"{n} must be an int >= {low}, got {v!r}")
        for n in ("ae_lr", "dit_lr"):
            if not getattr(self, n) > 0:
                raise ValueError(f"{n} must be > 0, got {getattr(self, n)!r}")
        if not 0 < self.min_lr_ratio <= 1:
            raise ValueError(f"min_lr_ratio must be in (0, 1], got {self.min_lr_ratio!r}")
        if not 0 <= self.ema_decay < 1:
            raise ValueError(f"ema_decay must be in [0, 1), got {self.ema_decay!r}")
        if not 0 <= self.one_step_fraction <= 1:
            raise ValueError(f"one_step_fraction must be in [0, 1], got {self.one_step_fraction!r}")
        if not self.detail_gate >= 0 or (self.detail_gate > 0 and not self.anchor_to_reference):
            raise ValueError(f"detail_gate must be >= 0 grey levels and needs --anchor-to-reference when > 0, got {self.detail_gate!r}")
        if not 0 <= self.no_contact_prob < 1:
            raise ValueError(f"no_contact_prob must be in [0, 1), got {self.no_contact_prob!r}")
        if any(c > s for c, s in zip(self.ae_crop, self.image_size)):
            raise ValueError(f"ae_crop {self.ae_crop} must fit in image_size {self.image_size}")
        if self.stage == "denoiser" and self.autoencoder_from is None and not (Path(self.out) / "autoencoder_state.json").is_file():
            raise ValueError("stage 'denoiser' needs --autoencoder-from or a trained autoencoder in --out")


# -- distributed helpers -----------------------------------------------------------------------

def setup_distributed() -> tuple[int, int]:
    """(rank, world size); initialises gloo when launched by torchrun with WORLD_SIZE > 1."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("gloo")
    return (dist.get_rank(), dist.get_world_size()) if world > 1 else (0, 1)


def barrier(world: int) -> None:
    if world > 1:
        dist.barrier()


def wrap(model: torch.nn.Module, world: int) -> torch.nn.Module:
    return torch.nn.parallel.DistributedDataParallel(model) if world > 1 else model


# -- state files (safetensors + JSON, no pickle) ------------------------------------------------

def save_state(path_stem: Path, modules: dict[str, torch.nn.Module], opt: torch.optim.Optimizer, meta: dict) -> None:
    """Write modules' weights + optimizer tensors to ``<stem>.safetensors`` and the rest to ``<stem>.json``."""
    tensors = {f"{name}.{k}": v.detach().cpu().contiguous() for name, m in modules.items() for k, v in m.state_dict().items()}
    sd = opt.state_dict()
    for pid, st in sd["state"].items():
        for k, v in st.items():
            tensors[f"optimizer.{pid}.{k}"] = (v if torch.is_tensor(v) else torch.tensor(v)).detach().cpu().contiguous()
    with atomic_path(path_stem.with_suffix(".safetensors")) as tmp:
        save_file(tensors, str(tmp))
    write_json(path_stem.with_suffix(".json"), {**meta, "param_groups": sd["param_groups"]})


def load_state(path_stem: Path, modules: dict[str, torch.nn.Module], opt: torch.optim.Optimizer) -> dict:
    """Restore what ``save_state`` wrote; returns the JSON metadata (with ``step``)."""
    meta = json.loads(path_stem.with_suffix(".json").read_text())
    tensors = load_file(str(path_stem.with_suffix(".safetensors")))
    for name, m in modules.items():
        prefix = f"{name}."
        m.load_state_dict({k[len(prefix):]: v for k, v in tensors.items() if k.startswith(prefix)}, strict=True)
    state: dict[int, dict] = {}
    for k, v in tensors.items():
        if k.startswith("optimizer."):
            _, pid, name = k.split(".", 2)
            state.setdefault(int(pid), {})[name] = v
    opt.load_state_dict({"state": state, "param_groups": meta["param_groups"]})
    return meta


def lr_at(step: int, total: int, peak: float, warmup: int, min_ratio: float) -> float:
    """Linear warm-up for ``warmup`` steps, then cosine decay from ``peak`` to ``min_ratio * peak``."""
    if step < warmup:
        return peak * (step + 1) / warmup
    p = min(1.0, (step - warmup) / max(1, total - warmup))
    return peak * (min_ratio + (1 - min_ratio) * 0.5 * (1 + math.cos(math.pi * p)))


def set_lr(opt: torch.optim.Optimizer, lr: float) -> None:
    for g in opt.param_groups:
        g["lr"] = lr


# -- stage 1: autoencoder ----------------------------------------------------------------------

CONTACT_LEVEL = 12.0 / 128  # residual magnitude (unit scale) above which a pixel counts as contact


def autoencoder_loss(recon: torch.Tensor, target: torch.Tensor, contact_weight: float = 0.0) -> torch.Tensor:
    """L1 + MSE + L1 of the image gradients (keeps contact edges sharp), per pixel weighted by
    ``1 + contact_weight`` where the target shows contact (contacts are a small share of the pad)."""
    w = 1.0 + contact_weight * (target.abs().amax(dim=1, keepdim=True) > CONTACT_LEVEL).float()
    d = recon - target
    dy, dx = d[..., 1:, :] - d[..., :-1, :], d[..., :, 1:] - d[..., :, :-1]
    return ((w * (d.abs() + d * d)).mean()
            + 0.5 * ((w[..., 1:, :] * dy.abs()).mean() + (w[..., :, 1:] * dx.abs()).mean()))


def crop_batch(data: PairData, rng: np.random.Generator, batch: int, crop: tuple[int, int]) -> torch.Tensor:
    """Random crops (with random flips) of random residuals, float (B, 3, ch, cw) in [-1, 1]; half of
    them centred on a contact pixel."""
    idx = rng.integers(0, len(data.residuals), size=batch)
    H, W = data.residuals.shape[1:3]
    ch, cw = crop
    out = np.empty((batch, ch, cw, 3), np.uint8)
    for k, i in enumerate(idx):
        y, x = rng.integers(0, H - ch + 1), rng.integers(0, W - cw + 1)
        if rng.random() < 0.5:  # half the crops centred on a contact pixel (contacts cover little of the pad)
            ys, xs = np.nonzero(contact_mask(data.residuals[i], threshold=12.0))
            if len(ys):
                j = rng.integers(0, len(ys))
                y = int(np.clip(ys[j] - ch // 2, 0, H - ch))
                x = int(np.clip(xs[j] - cw // 2, 0, W - cw))
        c = data.residuals[i, y:y + ch, x:x + cw]
        if rng.random() < 0.5:
            c = c[:, ::-1]
        if rng.random() < 0.5:
            c = c[::-1]
        out[k] = c
    return residual_to_unit(torch.from_numpy(out))


def train_autoencoder(cfg: TrainConfig, data: PairData, out: Path, rank: int, world: int) -> tuple[TactileAutoencoder, dict]:
    torch.manual_seed(cfg.seed)
    ae_cfg = AutoencoderConfig(image_size=cfg.image_size, channels=cfg.ae_channels, latent_channels=cfg.latent_channels)
    ae = TactileAutoencoder(ae_cfg)
    opt = torch.optim.AdamW(ae.parameters(), lr=cfg.ae_lr, weight_decay=0.0)
    stem = out / "autoencoder_state"
    step, wall = 0, 0.0
    if stem.with_suffix(".json").is_file():
        meta = load_state(stem, {"autoencoder": ae}, opt)
        step, wall = meta["step"], meta["wall_s"]
    model = wrap(ae, world)
    per_rank = max(1, cfg.ae_batch // world)
    bar = tqdm(total=cfg.ae_steps, initial=step, desc="autoencoder", unit="step", disable=rank != 0)
    t0, loss_ema = time.perf_counter(), None
    while step < cfg.ae_steps:
        rng = np.random.default_rng([cfg.seed, 1, rank, step])
        x = crop_batch(data, rng, per_rank, cfg.ae_crop)
        set_lr(opt, lr_at(step, cfg.ae_steps, cfg.ae_lr, cfg.warmup_steps, cfg.min_lr_ratio))
        loss = autoencoder_loss(model(x), x, cfg.ae_contact_weight)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(ae.parameters(), 1.0)
        opt.step()
        step += 1
        loss_ema = loss.item() if loss_ema is None else 0.98 * loss_ema + 0.02 * loss.item()
        bar.update()
        bar.set_postfix(loss=f"{loss_ema:.4f}")
        if rank == 0 and (step % cfg.checkpoint_every == 0 or step == cfg.ae_steps):
            save_state(stem, {"autoencoder": ae}, opt, {"step": step, "wall_s": wall + time.perf_counter() - t0,
                                                       "loss": loss_ema, "config": ae_cfg.to_dict(),
                                                       "trained_by": provenance(cfg)})
    bar.close()
    barrier(world)
    if world > 1 and step > 0:  # every rank reads rank 0's final state (identical weights anyway under DDP)
        load_state(stem, {"autoencoder": ae}, opt)
    meta = json.loads(stem.with_suffix(".json").read_text()) if stem.with_suffix(".json").is_file() else {"step": 0, "wall_s": 0.0}
    return ae.eval(), meta


def reuse_autoencoder(src: Path) -> tuple[TactileAutoencoder, dict]:
    """The trained autoencoder of another run folder (its state) or of a checkpoint folder (its weights),
    with the training that made it (``trained_by``: command and data) where the source records it."""
    stem = src / "autoencoder_state"
    if stem.with_suffix(".json").is_file():
        meta = json.loads(stem.with_suffix(".json").read_text())
        ae = TactileAutoencoder(AutoencoderConfig.from_dict(meta["config"]))
        tensors = load_file(str(stem.with_suffix(".safetensors")))
        ae.load_state_dict({k[len("autoencoder."):]: v for k, v in tensors.items() if k.startswith("autoencoder.")})
        if "trained_by" not in meta:  # states written before it was recorded: the run's saved arguments
            meta["trained_by"] = legacy_provenance(src)
        return ae.eval(), {**meta, "from": str(src)}
    config, ae, _ = load_checkpoint(src)
    card = json.loads((src / "model_card.json").read_text()) if (src / "model_card.json").is_file() else {}
    a = card.get("autoencoder", {})
    return ae.eval(), {"step": a.get("steps"), "wall_s": a.get("wall_s"), "loss": a.get("final_loss"),
                       "trained_by": a.get("trained_by"), "from": str(src), "config": config.autoencoder.to_dict()}


def provenance(cfg: TrainConfig) -> dict:
    """The command that reproduces ``cfg`` and its dataset (path, seed, image count from its meta.json)."""
    meta_path = Path(cfg.data) / "meta.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    return {"command": "python -m controltac_il.generator.train " + " ".join(_cli_args(cfg)),
            "data": {"path": str(cfg.data), "seed": meta.get("seed"), "images": meta.get("count")}}


def legacy_provenance(run: Path) -> dict | None:
    """``provenance`` rebuilt from a run folder's ``train_config.json`` (its latest invocation's arguments;
    None without one). Fields added to TrainConfig since take their defaults."""
    path = run / "train_config.json"
    if not path.is_file():
        return None
    saved = json.loads(path.read_text())
    return provenance(TrainConfig(**{f.name: saved[f.name] for f in dataclasses.fields(TrainConfig) if f.name in saved}))


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


def cached_latents(cfg: TrainConfig, ae: TactileAutoencoder, data: PairData, out: Path, rank: int, world: int) -> torch.Tensor:
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
        config = GeneratorConfig.from_dict(json.loads(stem.with_suffix(".json").read_text())["config"])
        tensors = load_file(str(stem.with_suffix(".safetensors")))
        return config, {k[len("ema."):]: v.float() for k, v in tensors.items() if k.startswith("ema.")}
    if not (src / "config.json").is_file():
        raise FileNotFoundError(f"denoiser_from: {src} holds neither a denoiser_state.json (run folder) nor a config.json (checkpoint)")
    config, _, dit = load_checkpoint(src)
    return config, dit.state_dict()


def denoiser_lineage(src: Path) -> list[dict]:
    """The trainings a ``--denoiser-from`` source went through, oldest first: its model card's lineage plus its
    own command, data, steps and wall time. Read from a checkpoint's card, or from a run folder's ``final/``
    card when that holds the run's latest state; empty where no card says (a run stopped mid-way)."""
    card_path = src / "model_card.json"
    if not card_path.is_file():
        card_path = src / "final" / "model_card.json"
        state = src / "denoiser_state.json"
        if not card_path.is_file() or (state.is_file() and json.loads(state.read_text())["step"]
                                       != json.loads(card_path.read_text())["denoiser"]["steps"]):
            return []
    card = json.loads(card_path.read_text())
    d, data = card.get("denoiser", {}), card.get("data", {})
    return d.get("lineage", []) + [{"command": card.get("command"), "data": {k: data.get(k) for k in ("path", "seed", "images")},
                                    "steps": d.get("steps"), "wall_s": d.get("wall_s")}]


def check_same_models(src: Path, source: GeneratorConfig, gcfg: GeneratorConfig) -> None:
    for part in ("dit", "autoencoder"):
        a, b = getattr(source, part).to_dict(), getattr(gcfg, part).to_dict()
        diff = {k: (a.get(k), b.get(k)) for k in a.keys() | b.keys() if a.get(k) != b.get(k)}
        if diff:
            raise ValueError(f"denoiser_from: {src} has another {part} config than this run "
                             f"(field: (source, this run)): {diff}")


@torch.no_grad()
def ema_update(ema: torch.nn.Module, model: torch.nn.Module, decay: float) -> None:
    for pe, pm in zip(ema.parameters(), model.parameters()):
        pe.lerp_(pm, 1 - decay)


def train_denoiser(cfg: TrainConfig, gcfg: GeneratorConfig, z: torch.Tensor, data: PairData, out: Path,
                   rank: int, world: int, init: dict[str, torch.Tensor] | None = None) -> tuple[ForceDiT, dict]:
    """Train (or resume) the DiT; ``init``: starting weights when there is no state to resume."""
    torch.manual_seed(cfg.seed + 1)
    dit = ForceDiT(gcfg.dit)
    ema = ForceDiT(gcfg.dit)
    ema.load_state_dict(dit.state_dict())
    opt = torch.optim.AdamW(dit.parameters(), lr=cfg.dit_lr, weight_decay=0.0)
    stem = out / "denoiser_state"
    step, wall, history = 0, 0.0, []
    if stem.with_suffix(".json").is_file():
        meta = load_state(stem, {"denoiser": dit, "ema": ema}, opt)
        step, wall, history = meta["step"], meta["wall_s"], meta.get("history", [])
    elif init is not None:
        dit.load_state_dict(init)
        ema.load_state_dict(init)
    # one entry per (re)start: resumed runs may change the step budget or the prediction target
    history = history + [{"from_step": step, "dit_steps": cfg.dit_steps, "prediction_type": gcfg.diffusion.prediction_type,
                          "lr": cfg.dit_lr, "batch": cfg.dit_batch, "one_step_fraction": cfg.one_step_fraction,
                          "denoiser_from": cfg.denoiser_from}]
    model = wrap(dit, world)
    sched = make_scheduler(gcfg.diffusion)
    c = gcfg.autoencoder.latent_channels
    lat = torch.tensor(gcfg.latent_scale).view(1, c, 1, 1)
    dsc = torch.tensor(gcfg.delta_scale).view(1, c, 1, 1)
    per_rank = max(1, cfg.dit_batch // world)
    bar = tqdm(total=cfg.dit_steps, initial=step, desc=f"denoiser ({cfg.dit_preset})", unit="step", disable=rank != 0)
    t0, loss_ema = time.perf_counter(), None
    while step < cfg.dit_steps:
        rng = np.random.default_rng([cfg.seed, 2, rank, step])
        ref, tgt, df = sample_pairs(data, per_rank, rng, cfg.no_contact_prob)
        x0 = (z[tgt] - z[ref]) / dsc
        zr = z[ref] / lat
        g = torch.Generator().manual_seed(int(rng.integers(0, 2**62)))
        noise = torch.randn(x0.shape, generator=g)
        t = torch.randint(0, gcfg.diffusion.num_train_timesteps, (per_rank,), generator=g)
        if cfg.one_step_fraction > 0:
            t[torch.rand(per_rank, generator=g) < cfg.one_step_fraction] = gcfg.diffusion.num_train_timesteps - 1
        xt = sched.add_noise(x0, noise, t)
        target = noise if gcfg.diffusion.prediction_type == "epsilon" else x0
        set_lr(opt, lr_at(step, cfg.dit_steps, cfg.dit_lr, cfg.warmup_steps, cfg.min_lr_ratio))
        pred = model(xt, zr, t, torch.from_numpy(df))
        loss = 0.5 * F.l1_loss(pred, target) + 0.5 * F.mse_loss(pred, target)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(dit.parameters(), 1.0)
        opt.step()
        step += 1
        ema_update(ema, dit, min(cfg.ema_decay, (1 + step) / (10 + step)))
        loss_ema = loss.item() if loss_ema is None else 0.98 * loss_ema + 0.02 * loss.item()
        bar.update()
        bar.set_postfix(loss=f"{loss_ema:.4f}")
        if rank == 0 and (step % cfg.checkpoint_every == 0 or step == cfg.dit_steps):
            save_state(stem, {"denoiser": dit, "ema": ema}, opt,
                       {"step": step, "wall_s": wall + time.perf_counter() - t0, "loss": loss_ema, "config": gcfg.to_dict(),
                        "history": history})
    bar.close()
    barrier(world)
    if stem.with_suffix(".json").is_file():
        load_state(stem, {"denoiser": dit, "ema": ema}, opt)
        meta = json.loads(stem.with_suffix(".json").read_text())
    else:
        meta = {"step": 0, "wall_s": 0.0}
    return ema.eval(), meta


# -- driver ------------------------------------------------------------------------------------

def run(cfg: TrainConfig) -> Path:
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

    if cfg.autoencoder_from is not None:
        ae, ae_meta = reuse_autoencoder(Path(cfg.autoencoder_from))
        if tuple(ae.config.image_size) != cfg.image_size:
            raise ValueError(f"--autoencoder-from has image_size {ae.config.image_size}, this run {cfg.image_size}")
    elif cfg.stage in ("all", "autoencoder"):
        ae, ae_meta = train_autoencoder(cfg, data, out, rank, world)
    else:
        ae, ae_meta = reuse_autoencoder(out)
    if cfg.stage == "autoencoder":
        return out

    z = cached_latents(cfg, ae, data, out, rank, world)
    source, init = (None, None) if cfg.denoiser_from is None else source_denoiser(Path(cfg.denoiser_from))
    lat, dsc = latent_scales(z, data, cfg.seed) if source is None else (source.latent_scale, source.delta_scale)
    c = ae.config.latent_channels
    gcfg = GeneratorConfig(
        autoencoder=ae.config,
        dit=DIT_PRESETS[cfg.dit_preset](in_channels=c, patch_size=cfg.dit_patch, conv_head_width=cfg.dit_conv_head),
        diffusion=DiffusionConfig(prediction_type=cfg.prediction_type, default_steps=cfg.default_steps),
        latent_scale=lat, delta_scale=dsc, anchor_to_reference=cfg.anchor_to_reference, detail_gate=cfg.detail_gate,
    )
    if source is not None:
        check_same_models(Path(cfg.denoiser_from), source, gcfg)
    dit, dit_meta = train_denoiser(cfg, gcfg, z, data, out, rank, world, init)
    final = out / "final"
    if rank == 0:
        meta = json.loads((Path(cfg.data) / "meta.json").read_text()) if (Path(cfg.data) / "meta.json").is_file() else {}
        card = {
            "model": "controltac-il stage-1 force-control generator (tactile autoencoder + ΔF-conditioned DiT + DDIM)",
            "command": "python -m controltac_il.generator.train " + " ".join(_cli_args(cfg)),
            "data": {"path": str(cfg.data), "seed": meta.get("seed"), "objects": meta.get("objects"),
                     "images": int(len(data.residuals) - len(data.no_contact)), "pose_groups": len(data.groups),
                     "no_contact_frames": int(len(data.no_contact)), "fz_range": meta.get("fz_range"),
                     "optics": meta.get("optics"), "render_size": [meta.get("spec", {}).get("height"), meta.get("spec", {}).get("width")]},
            "autoencoder": {"steps": ae_meta.get("step"), "wall_s": ae_meta.get("wall_s"), "final_loss": ae_meta.get("loss"),
                            "from": ae_meta.get("from"), "trained_by": ae_meta.get("trained_by")},
            "denoiser": {"preset": cfg.dit_preset, "steps": dit_meta["step"], "wall_s": dit_meta["wall_s"],
                         "final_loss": dit_meta.get("loss"), "from": cfg.denoiser_from, "batch": cfg.dit_batch, "lr": cfg.dit_lr,
                         "lineage": [] if cfg.denoiser_from is None else denoiser_lineage(Path(cfg.denoiser_from)),
                         "parameters": sum(p.numel() for p in dit.parameters()), "history": dit_meta.get("history")},
            "autoencoder_parameters": sum(p.numel() for p in ae.parameters()),
            "world_size": world,
            "total_wall_s": time.perf_counter() - t_start,
            "machine": {"cpu_count": os.cpu_count(), "torch": torch.__version__, "python": platform.python_version()},
            "weights_dtype": "float16",
            "validated_range": {"fz_n": [1.0, 10.0], "abs_shear_n": 1.0},
        }
        save_checkpoint(final, gcfg, ae, dit, dtype=torch.float16, model_card=card)
        print(f"wrote {final}")
    barrier(world)
    if world > 1:
        dist.destroy_process_group()
    return final


def _cli_args(cfg: TrainConfig) -> list[str]:
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


def parse_args(argv=None) -> TrainConfig:
    d = TrainConfig.__dataclass_fields__
    p = argparse.ArgumentParser(
        prog="python -m controltac_il.generator.train",
        description="Train the stage-1 force-control generator (autoencoder, then the ΔF-conditioned DiT on "
                    "cached latents) on a sensor-model dataset. Writes periodic resumable states and a final "
                    "fp16 checkpoint with a model card to OUT/final. Launch with torchrun for data parallelism (gloo, CPU).")
    p.add_argument("--data", required=True, help="dataset folder (controltac_il.tactile.dataset.write_dataset layout)")
    p.add_argument("--out", required=True, help="run folder for states, latents and OUT/final")
    p.add_argument("--stage", choices=STAGES, default="all", help="which stage(s) to train (default: all)")
    p.add_argument("--autoencoder-from", default=None, help="reuse the autoencoder of this run or checkpoint folder")
    p.add_argument("--denoiser-from", default=None,
                   help="start the DiT from this run or checkpoint folder's DiT (fine-tuning; same architecture and autoencoder)")
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
    for name in ("dit_patch", "ae_steps", "ae_batch", "dit_steps", "dit_batch", "warmup_steps", "checkpoint_every", "seed",
                 "no_contact_frames", "threads"):
        p.add_argument("--" + name.replace("_", "-"), type=int, default=d[name].default)
    for name in ("ae_lr", "ae_contact_weight", "dit_lr", "min_lr_ratio", "ema_decay", "no_contact_prob"):
        p.add_argument("--" + name.replace("_", "-"), type=float, default=d[name].default)
    p.add_argument("--ae-crop", type=int, nargs=2, default=d["ae_crop"].default, metavar=("H", "W"))
    p.add_argument("--anchor-to-reference", action="store_true", help="output = reference + decoded change")
    p.add_argument("--detail-gate", type=float, default=0.0, metavar="G",
                   help="with anchoring: keep the reference's fine detail only where the target keeps its contact; "
                        "G grey levels (default 0 = always keep; the shipped default uses 4)")
    a = vars(p.parse_args(argv))
    resume = a.pop("resume")
    cfg = TrainConfig(**a)
    out = Path(cfg.out)
    has_state = any((out / f"{s}_state.json").is_file() for s in ("autoencoder", "denoiser"))
    if has_state and not resume:
        p.error(f"{out} already holds training states: pass --resume to continue or choose another --out")
    return cfg


def main(argv=None) -> None:
    run(parse_args(argv))


if __name__ == "__main__":
    main()
