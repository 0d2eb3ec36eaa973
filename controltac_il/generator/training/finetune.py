"""Fine-tuning a generator on one sensor's presses: its autoencoder, then its DiT on the moved latents
(``python -m controltac_il.generator.training stage1 --stage denoiser --autoencoder-from BASE --ae-finetune-steps A
--denoiser-from BASE`` with the base's own DiT flags). Used by ``python -m controltac_il.calibrate`` and
``benchmarks.finetune``."""

from __future__ import annotations

from pathlib import Path

from controltac_il.checkpoint import read_json


def base_flags(base: Path) -> list[str]:
    """The DiT flags of the base checkpoint's own training command (its model card), for a compatible DiT (the
    reference-force condition included)."""
    command = read_json(Path(base) / "model_card.json")["command"].split()
    keep, out = {"--dit-preset", "--dit-patch", "--dit-conv-head", "--prediction-type", "--default-steps",
                 "--one-step-fraction"}, []
    for k, v in zip(command, command[1:]):
        if k in keep:
            out += [k, v]
    return out + [flag for flag in ("--anchor-to-reference", "--reference-force") if flag in command]


def fine_tune(base: Path, data: Path, out: Path, steps: int, lr: float, ae_steps: int = 0, batch: int = 64,
              threads: int | None = None, device: str = "cpu") -> Path:
    """Fine-tune ``base``'s autoencoder (``ae_steps``) and then its DiT (``steps``, batch ``batch``) on the
    dataset folder ``data`` into the run folder ``out`` on ``device`` (resumed where a run stopped; kept when
    done); returns the checkpoint ``out / "final"``. RuntimeError when the training stops with an error."""
    from controltac_il.generator import ForceGenerator
    from controltac_il.generator.training.cli import main as train

    base, out = Path(base), Path(out)
    if not (out / "final" / "model_card.json").is_file():
        config = ForceGenerator.from_pretrained(base).config
        gate, size = config.detail_gate, [str(v) for v in config.image_size]
        argv = ["stage1", "--data", str(data), "--out", str(out), "--image-size", *size, "--stage", "denoiser",
                "--autoencoder-from", str(base),
                "--denoiser-from", str(base), *base_flags(base), "--dit-steps", str(steps), "--dit-batch", str(batch),
                "--dit-lr", str(lr), "--warmup-steps", str(min(20, max(steps // 5, 1))), "--detail-gate", str(gate),
                "--checkpoint-every", str(max(min(steps, 200), 1))]
        if ae_steps:
            argv += ["--ae-finetune-steps", str(ae_steps), "--ae-lr", str(lr), "--ae-crop", "64", "80"]
        if threads:
            argv += ["--threads", str(threads)]
        if device != "cpu":
            argv += ["--device", device]
        resume = any((out / f"{s}_state.json").is_file() for s in ("autoencoder_finetune", "denoiser"))
        rc = train(argv + (["--resume"] if resume else []))
        if rc != 0:
            raise RuntimeError(f"fine-tuning the generator on {data} stopped with exit code {rc}")
    return out / "final"
