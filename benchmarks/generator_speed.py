"""The generator's throughput per checkpoint, sampler steps, batch size, dtype and device, with its error beside it.

    python -m benchmarks.generator_speed --out speed.json [--device cuda] [--checkpoints fast default quality]
        [--batch-sizes 32 256 auto] [--dtypes float32 bfloat16] [--steps 1 2 5]

Images/s (per round: the median of ``--repeats`` ``generate`` calls after one warm-up, output back on the CPU, so
the time includes the device's work; reported: the median over ``--rounds`` rounds, each timing every checkpoint,
with each round's figure beside it) for frames at the GelSight Mini's 240×320 and at 120×160. A call generates
``CALL_BATCHES`` batches of an int batch size, or ``AUTO_ROWS`` frames at ``auto`` (the largest batch the device's
free memory holds, ``batching``; its value is recorded). The frames are sensor-model presses of a held-out object:
throughput does not depend on what the frames show. Beside each speed, the error of that checkpoint, steps and
dtype on the device: MSE ÷ a reference copy's on ``benchmarks.generator``'s unseen-object pairs of that size
(``unseen_240``, ``unseen``; the bytes do not depend on the batch size). On CUDA also the peak memory allocated.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from benchmarks.common import base_parser, median_time, print_table, write_results
from benchmarks.generator import eval_pairs
from benchmarks.generator_fa import SIZES
from benchmarks.generator_frontier import FRONTIER
from controltac_il.generator import ForceGenerator
from controltac_il.config import AUTO, parse_batch_size
from controltac_il.generator.batching import free_bytes, rows_per_batch
from controltac_il.generator.pipeline import chunk_rows
from controltac_il.metrics import mse
from controltac_il.tactile import HELDOUT_OBJECTS, SensorSpec, TactileSensor, from_residual

ERROR_SPLITS = {"240": "unseen_240", "120": "unseen"}  # benchmarks.generator's pairs of each size
STEPS = (1, 2, 5)
CALL_BATCHES = 1  # an int batch size is timed over calls of this many batches
AUTO_ROWS = 2048  # frames per call at batch "auto" (and so the most it can pick)
DTYPES = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}

PROG = "python -m benchmarks.generator_speed"


def frames(size: tuple[int, int], count: int) -> tuple[np.ndarray, np.ndarray]:
    """(residuals uint8 (count, H, W, 3), ΔF float32 (count, 3) N): 32 presses of the held-out objects at 2-9 N,
    repeated to ``count``, each asked for +1 N."""
    sensor = TactileSensor(SensorSpec.gelsight_mini().scaled(*size))
    rng = np.random.default_rng(0)
    res = [sensor.press(HELDOUT_OBJECTS[k % len(HELDOUT_OBJECTS)], (0.0, 0.0, 0.0), (0.0, 0.0, float(rng.uniform(2, 9))),
                        noise_seed=k).residual for k in range(min(count, 32))]
    return np.resize(np.stack(res), (count, *size, 3)), np.tile(np.float32([[0.0, 0.0, 1.0]]), (count, 1))


def call_rows(batch) -> int:
    """Frames per timed call at this batch size (an int, or "auto")."""
    return AUTO_ROWS if batch == AUTO else CALL_BATCHES * int(batch)


def time_round(gens: dict, a, data: dict, order: list[str]) -> tuple[dict, dict]:
    """{(checkpoint, dtype, frames, steps, batch): img/s} of one round: every setting of every generator in
    ``order`` once (median of ``a.repeats`` calls after one warm-up); on CUDA also {(checkpoint, dtype, frames):
    peak MB allocated by that size's settings} (the footprint measured first: it resets the peak itself)."""
    out, peaks = {}, {}
    cuda = a.device.startswith("cuda")
    for key in order:
        gen = gens[key]
        for size, (refs, delta) in data.items():
            gen.footprint(refs.shape[1:3])
            if cuda:
                torch.cuda.reset_peak_memory_stats()
            for steps in a.steps:
                for batch in a.batch_sizes:
                    n = min(call_rows(batch), len(refs))
                    def once():
                        gen.generate(refs[:n], delta[:n], steps=steps, seed=0, batch_size=batch)
                    out[(*key, size, steps, batch)] = n / median_time(once, repeats=a.repeats, warmup=1)
            peaks[(*key, size)] = torch.cuda.max_memory_allocated() / 2**20 if cuda else None
    return out, peaks


def errors(gens: dict, steps: tuple[int, ...], pairs: dict) -> dict:
    """{(checkpoint, dtype, frames, steps): MSE ÷ a copy's} on each size's unseen-object pairs."""
    out = {}
    for key, gen in gens.items():
        for size, (refs, tgts, rf, tf, bg) in pairs.items():
            copy = mse(from_residual(refs, bg), from_residual(tgts, bg)).mean()
            for s in steps:
                pred = gen.generate(refs, tf - rf, steps=s, seed=0, batch_size=AUTO)
                out[(*key, size, s)] = float(mse(from_residual(pred, bg), from_residual(tgts, bg)).mean() / copy)
    return out


def time_checkpoints(a, data: dict, pairs: dict | None) -> list[dict]:
    """One row per (checkpoint, dtype, frames, steps, batch): img/s as the median over rounds, each round timing
    every generator (the order rotated round to round, so that a drift of the machine's speed spreads over all),
    with the rounds' own figures, the batch ``auto`` picked and the error beside it."""
    gens = {(n, d): ForceGenerator.from_pretrained(n, device=a.device, dtype=DTYPES[d])
            for n in a.checkpoints for d in a.dtypes}
    keys = list(gens)
    per_round = [time_round(gens, a, data, keys[r % len(keys):] + keys[:r % len(keys)]) for r in range(a.rounds)]
    error = errors(gens, a.steps, pairs) if pairs else {}
    rows = []
    for key in per_round[0][0]:
        name, dtype, size, steps, batch = key
        gen, values = gens[(name, dtype)], [r[key] for r, _ in per_round]
        picked = rows_per_batch(batch, gen.footprint(SIZES[size]), free_bytes(gen.device), chunk_rows(gen.device),
                                min(call_rows(batch), len(data[size][0])))  # rows a batch ran, padding included
        rows.append({"checkpoint": name, "hash": gen.checkpoint_hash, "dtype": dtype, "frames": size, "steps": steps,
                     "batch": batch, "batch_rows": picked, "chunk": chunk_rows(gen.device),
                     "dit_parameters": sum(p.numel() for p in gen.denoiser.parameters()),
                     "img_per_s": float(np.median(values)), "img_per_s_rounds": values,
                     "mse_ratio_to_copy": error.get((name, dtype, size, steps)),
                     "peak_cuda_mb": per_round[-1][1][(name, dtype, size)]})
    return rows


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.splitlines()[0])
    p.add_argument("--checkpoints", nargs="+", default=["fast", "default", *FRONTIER],
                   help="shipped names (the presets, the frontier's sizes) or checkpoint folders (default: all five)")
    p.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    p.add_argument("--threads", type=int, default=2, help="torch threads on the CPU (default 2, the target machine's)")
    p.add_argument("--batch-sizes", nargs="+", type=parse_batch_size, default=[32], metavar="B",
                   help="batch sizes to time: ints and/or auto (default: 32)")
    p.add_argument("--dtypes", nargs="+", choices=list(DTYPES), default=["float32"], help="default: float32")
    p.add_argument("--steps", nargs="+", type=int, default=list(STEPS), help="DDIM steps (default 1 2 5)")
    p.add_argument("--pairs", type=int, default=None, help="error pairs per size (default 96, quick 8; 0: no error)")
    p.add_argument("--cache", type=Path, default=Path("/tmp/controltac_generator_bench"), help="error pairs' cache")
    p.add_argument("--repeats", type=int, default=None, help="timed calls per setting and round (default 5, quick 2)")
    p.add_argument("--rounds", type=int, default=None, help="rounds over every checkpoint (default 3, quick 1)")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    a.repeats, a.rounds = a.repeats or (2 if a.quick else 5), a.rounds or (1 if a.quick else 3)
    count = max(call_rows(b) for b in a.batch_sizes) if not a.quick else 8
    if a.quick:
        a.batch_sizes = [b if b == AUTO else min(int(b), 4) for b in a.batch_sizes]
    data = {k: frames(hw, count) for k, hw in SIZES.items()}
    n_pairs = (8 if a.quick else 96) if a.pairs is None else a.pairs
    pairs = {k: eval_pairs(a.cache, split, poses=2 if a.quick else 8, forces=4 if a.quick else 6, max_pairs=n_pairs)
             for k, split in ERROR_SPLITS.items()} if n_pairs else None
    rows = time_checkpoints(a, data, pairs)
    print_table([{**r, "rounds": " ".join(f"{v:.1f}" for v in r["img_per_s_rounds"])} for r in rows],
                ["checkpoint", "dtype", "frames", "steps", "batch", "batch_rows", "img_per_s", "rounds",
                 "mse_ratio_to_copy", "peak_cuda_mb"], title=f"generator throughput on {a.device}")
    return write_results(a.out, {"settings": {"device": a.device, "threads": a.threads, "batch_sizes": a.batch_sizes,
                                              "dtypes": a.dtypes, "steps": a.steps, "repeats": a.repeats,
                                              "rounds": a.rounds, "quick": a.quick, "error_pairs": n_pairs,
                                              "frames": {k: list(v) for k, v in SIZES.items()},
                                              "auto_rows": AUTO_ROWS, "call_batches": CALL_BATCHES},
                                 "rows": rows})


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
