"""What batch-independent generation costs: the shipped generator's frames/s with forward passes in whole chunks
of ``GENERATION_CHUNK`` rows (shipped, 4) against single rows allowed (1: a row per pass, where torch's CPU
kernels may differ with the batch, so a frame's bytes would depend on its batch-mates).

    python -m benchmarks.generation_chunk --out benchmarks/results/generation_chunk.json [--quick]

Two call patterns on GelSight-style residuals (the sensor model, 240x320): ``online`` (one frame a call, as
ForceAugment's online mode generates) and ``cache`` (32 frames a call, as a cache build does). Frames/s from the
median CPU time of this process over repeats (``time.process_time``: other load on the shared machine does not
inflate it), the chunk settings taking turns; torch threads as given (``--threads``, default 1, as in DataLoader
workers and the verdict's units). Also reports whether the two settings' bytes differ (they may for chunk 1).
"""

from __future__ import annotations

import time

import numpy as np
import torch

from benchmarks.common import base_parser, median_time, print_table, write_results
from controltac_il.generator import ForceGenerator
from controltac_il.generator import pipeline
from controltac_il.tactile import SensorSpec, TactileSensor

PROG = "python -m benchmarks.generation_chunk"


def residuals(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` sensor-model contact residuals (n, 240, 320, 3) and ΔF (n, 3) N."""
    sensor, rng = TactileSensor(SensorSpec.gelsight_mini(), seed=seed), np.random.default_rng(seed)
    objs = ("big_sphere", "cross", "usb_c", "slim_cylinder")
    ref = np.stack([sensor.press(objs[i % len(objs)], tuple(rng.uniform(-0.5, 0.5, 3)), (0.0, 0.0, rng.uniform(2, 8)),
                                 noise_seed=i).residual for i in range(n)])
    return ref, np.column_stack([np.zeros(n), np.zeros(n), rng.uniform(-2, 2, n)])


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.split("\n\n")[0])
    p.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    p.add_argument("--repeats", type=int, default=5, help="timed repeats per setting (medians)")
    args = p.parse_args(argv)
    if args.threads < 1 or args.repeats < 1:
        p.error("--threads and --repeats must be >= 1")
    torch.set_num_threads(args.threads)
    gen = ForceGenerator.from_pretrained()
    n = 8 if args.quick else 32
    ref, df = residuals(n)
    seeds = list(range(n))
    calls = {"online": lambda: [gen.generate(ref[i:i + 1], df[i:i + 1], seed=[i]) for i in range(n)],
             "cache": lambda: gen.generate(ref, df, seed=seeds, batch_size=32)}
    shipped, rows, outputs = pipeline.GENERATION_CHUNK, [], {}
    try:
        for pattern, call in calls.items():
            for chunk in (1, shipped):  # the settings take turns, one warm-up each
                pipeline.GENERATION_CHUNK = chunk
                out = call()
                outputs[pattern, chunk] = np.concatenate(out) if isinstance(out, list) else out
                t = median_time(call, repeats=1 if args.quick else args.repeats, warmup=0, clock=time.process_time)
                rows.append({"pattern": pattern, "chunk": chunk, "frames": n, "cpu_s": round(t, 3),
                             "frames_per_cpu_s": round(n / t, 2)})
    finally:
        pipeline.GENERATION_CHUNK = shipped
    for r in rows:
        r["bytes_differ_from_cache_chunk"] = int((outputs[r["pattern"], r["chunk"]] != outputs["cache", shipped]).sum())
    base = {r["pattern"]: r["frames_per_cpu_s"] for r in rows if r["chunk"] == 1}
    for r in rows:
        r["relative_to_chunk_1"] = round(r["frames_per_cpu_s"] / base[r["pattern"]], 3)
    print_table(rows, ["pattern", "chunk", "frames_per_cpu_s", "relative_to_chunk_1", "bytes_differ_from_cache_chunk"],
                "Shipped generator, 240x320, default sampler steps")
    return write_results(args.out, {"benchmark": "generation_chunk", "threads": args.threads, "shipped_chunk": shipped,
                                    "rows": rows})


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
