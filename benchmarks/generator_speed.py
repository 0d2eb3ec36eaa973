"""The generator's throughput alone, per checkpoint, sampler steps and device: the speed column of the frontier.

    python -m benchmarks.generator_speed --out speed.json [--device cuda] [--checkpoints fast default quality]

Images/s at batch 32 (per round: the median of ``--repeats`` ``generate`` calls after one warm-up, output back on
the CPU, so the time includes the device's work; reported: the median over ``--rounds`` rounds, each timing every
checkpoint, with each round's figure beside it) for frames at the GelSight Mini's 240×320 and at 120×160, DDIM steps 1, 2
and 5; the DiT's parameter count; on CUDA the peak memory a batch of 32 allocates. The frames are sensor-model
presses of a held-out object: throughput does not depend on what the frames show. Error is measured by
``benchmarks.generator`` (CPU); this module times, so that a GPU session can time every size in one call.
"""

from __future__ import annotations

import numpy as np
import torch

from benchmarks.common import base_parser, median_time, print_table, write_results
from benchmarks.generator_frontier import FRONTIER
from controltac_il.generator import ForceGenerator
from controltac_il.tactile import HELDOUT_OBJECTS, SensorSpec, TactileSensor

SIZES = {"240": (240, 320), "120": (120, 160)}
STEPS = (1, 2, 5)
BATCH = 32


def frames(size: tuple[int, int], count: int = BATCH) -> tuple[np.ndarray, np.ndarray]:
    """(residuals uint8 (count, H, W, 3), ΔF float32 (count, 3) N): presses of the held-out objects at 2-9 N, each
    asked for +1 N."""
    sensor = TactileSensor(SensorSpec.gelsight_mini().scaled(*size))
    rng = np.random.default_rng(0)
    res = [sensor.press(HELDOUT_OBJECTS[k % len(HELDOUT_OBJECTS)], (0.0, 0.0, 0.0), (0.0, 0.0, float(rng.uniform(2, 9))),
                        noise_seed=k).residual for k in range(count)]
    return np.stack(res), np.tile(np.float32([[0.0, 0.0, 1.0]]), (count, 1))


def time_round(gens: dict, device: str, repeats: int, data: dict, order: list[str]) -> tuple[dict, dict]:
    """{(checkpoint, frames, steps): img/s} of one round: every setting of every checkpoint in ``order`` once
    (median of ``repeats`` calls after one warm-up); on CUDA also {checkpoint: peak MB allocated by its settings}."""
    out, peaks = {}, {}
    for name in order:
        gen = gens[name]
        if device.startswith("cuda"):
            torch.cuda.reset_peak_memory_stats()
        for size, (refs, delta) in data.items():
            for steps in STEPS:
                def once():
                    gen.generate(refs, delta, steps=steps, seed=0, batch_size=BATCH)
                out[(name, size, steps)] = len(refs) / median_time(once, repeats=repeats, warmup=1)
        peaks[name] = torch.cuda.max_memory_allocated() / 2**20 if device.startswith("cuda") else None
    return out, peaks


def time_checkpoints(names: list[str], device: str, repeats: int, rounds: int, data: dict) -> list[dict]:
    """One row per (checkpoint, frames, steps): img/s as the median over ``rounds`` rounds, each round timing
    every checkpoint (the order rotated round to round, so that a drift of the machine's speed spreads over all),
    with the rounds' own figures beside it."""
    gens = {n: ForceGenerator.from_pretrained(n, device=device) for n in names}
    per_round = [time_round(gens, device, repeats, data, names[r % len(names):] + names[:r % len(names)])
                 for r in range(rounds)]
    rows = []
    for key in per_round[0][0]:
        name, size, steps = key
        values = [r[key] for r, _ in per_round]
        rows.append({"checkpoint": name, "hash": gens[name].checkpoint_hash, "frames": size, "steps": steps,
                     "dit_parameters": sum(p.numel() for p in gens[name].denoiser.parameters()),
                     "img_per_s_b32": float(np.median(values)), "img_per_s_rounds": values,
                     "peak_cuda_mb": per_round[0][1][name]})
    return rows


def main(argv=None) -> dict:
    p = base_parser(__doc__.splitlines()[0])
    p.add_argument("--checkpoints", nargs="+", default=["fast", "default", *FRONTIER],
                   help="shipped names (the presets, the frontier's sizes) or checkpoint folders (default: all five)")
    p.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    p.add_argument("--threads", type=int, default=2, help="torch threads on the CPU (default 2, the target machine's)")
    p.add_argument("--repeats", type=int, default=None, help="timed calls per setting and round (default 5, quick 2)")
    p.add_argument("--rounds", type=int, default=None, help="rounds over every checkpoint (default 3, quick 1)")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    repeats, rounds = a.repeats or (2 if a.quick else 5), a.rounds or (1 if a.quick else 3)
    data = {k: frames(hw, 4 if a.quick else BATCH) for k, hw in SIZES.items()}
    rows = time_checkpoints(a.checkpoints, a.device, repeats, rounds, data)
    print_table([{**r, "rounds": " ".join(f"{v:.1f}" for v in r["img_per_s_rounds"])} for r in rows],
                ["checkpoint", "dit_parameters", "frames", "steps", "img_per_s_b32", "rounds", "peak_cuda_mb"],
                title=f"generator throughput on {a.device}")
    return write_results(a.out, {"settings": {"device": a.device, "threads": a.threads, "batch": BATCH,
                                              "repeats": repeats, "rounds": rounds, "quick": a.quick,
                                              "frames": {k: list(v) for k, v in SIZES.items()}},
                                 "rows": rows})


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard("python -m benchmarks.generator_speed", lambda: main() and 0))
