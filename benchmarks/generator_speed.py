"""The generator's throughput alone, per checkpoint, sampler steps and device: the speed column of the frontier.

    python -m benchmarks.generator_speed --checkpoints fast default quality --device cuda --out speed.json

Images/s at batch 32 (median of ``--repeats`` ``generate`` calls after one warm-up, output back on the CPU, so
the time includes the device's work) for frames at the GelSight Mini's 240×320 and at 120×160, DDIM steps 1, 2
and 5; the DiT's parameter count; on CUDA the peak memory a batch of 32 allocates. The frames are sensor-model
presses of a held-out object: throughput does not depend on what the frames show. Error is measured by
``benchmarks.generator`` (CPU); this module times, so that a GPU session can time every size in one call.
"""

from __future__ import annotations

import numpy as np
import torch

from benchmarks.common import base_parser, median_time, print_table, write_results
from controltac_il.generator import ForceGenerator
from controltac_il.tactile import HELDOUT_OBJECTS, SensorSpec, TactileSensor
from controltac_il.tactile.residual import to_residual

SIZES = {"240": (240, 320), "120": (120, 160)}
STEPS = (1, 2, 5)
BATCH = 32


def frames(size: tuple[int, int], count: int = BATCH) -> tuple[np.ndarray, np.ndarray]:
    """(residuals uint8 (count, H, W, 3), ΔF float32 (count, 3) N): presses of the held-out objects at 2-9 N, each
    asked for +1 N."""
    sensor = TactileSensor(SensorSpec.gelsight_mini().scaled(*size))
    rng = np.random.default_rng(0)
    res = [to_residual(sensor.press(HELDOUT_OBJECTS[k % len(HELDOUT_OBJECTS)], (0.0, 0.0, 0.0),
                                    (0.0, 0.0, float(rng.uniform(2, 9))), noise_seed=k).image, sensor.background)
           for k in range(count)]
    return np.stack(res), np.tile(np.float32([[0.0, 0.0, 1.0]]), (count, 1))


def time_checkpoint(name: str, device: str, repeats: int, data: dict) -> list[dict]:
    """One row per (frame size, steps) for checkpoint ``name`` on ``device``."""
    gen = ForceGenerator.from_pretrained(name, device=device)
    params = sum(p.numel() for p in gen.denoiser.parameters())
    rows = []
    for size, (refs, delta) in data.items():
        for steps in STEPS:
            def once():
                gen.generate(refs, delta, steps=steps, seed=0, batch_size=BATCH)
            if device.startswith("cuda"):
                torch.cuda.reset_peak_memory_stats()
            seconds = median_time(once, repeats=repeats, warmup=1)
            peak = torch.cuda.max_memory_allocated() / 2**20 if device.startswith("cuda") else None
            rows.append({"checkpoint": name, "hash": gen.checkpoint_hash, "dit_parameters": params, "frames": size,
                         "steps": steps, "img_per_s_b32": BATCH / seconds, "peak_cuda_mb": peak})
    return rows


def main(argv=None) -> dict:
    p = base_parser(__doc__.splitlines()[0])
    p.add_argument("--checkpoints", nargs="+", default=["fast", "default"],
                   help="shipped names or checkpoint folders (default: fast default)")
    p.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    p.add_argument("--threads", type=int, default=2, help="torch threads on the CPU (default 2, the target machine's)")
    p.add_argument("--repeats", type=int, default=None, help="timed calls per setting (default 7, quick 2)")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    repeats = a.repeats or (2 if a.quick else 7)
    data = {k: frames(hw, 4 if a.quick else BATCH) for k, hw in SIZES.items()}
    rows = [r for name in a.checkpoints for r in time_checkpoint(name, a.device, repeats, data)]
    print_table([{k: (f"{v:.1f}" if isinstance(v, float) else v) for k, v in r.items() if k != "hash"} for r in rows],
                ["checkpoint", "dit_parameters", "frames", "steps", "img_per_s_b32", "peak_cuda_mb"],
                title=f"generator throughput on {a.device}")
    return write_results(a.out, {"settings": {"device": a.device, "threads": a.threads, "batch": BATCH,
                                              "repeats": repeats, "quick": a.quick,
                                              "frames": {k: list(v) for k, v in SIZES.items()}},
                                 "rows": rows})


if __name__ == "__main__":
    main()
