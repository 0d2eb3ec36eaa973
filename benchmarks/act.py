"""ACT benchmark: inference latency per chunk, training throughput, and the paper's IL experiment in sim.

    python -m benchmarks.act --out act.json            # full: 50 demos, real vs ForceAugment 1/2/4
    python -m benchmarks.act --steps 4000 --jobs 2 --out act.json   # two variants at a time (2 cores)
    python -m benchmarks.act --quick --out act.json    # CI: tiny sizes, real vs ForceAugment 1

Experiment (ControlTac, imitation learning): train the cpu-preset ACT on the same demos with real data
only and with 1, 2 and 4 ForceAugment copies, then deploy each through the control loop in the MuJoCo
scene on seeded episodes, once at the demos' grip-force range and once with the grip force shifted
outside it. Success rates come with Wilson 95 % intervals. Results are written after every stage, so
an interrupted run still reports what finished (``"status"`` per row).
"""

from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks.common import base_parser, median_time, print_table, quartiles, timings, write_results
from controltac_il.app.experiment import policy_meta
from controltac_il.streams import LOOP, LOOP_STATE, background_key, image_key, tactile_key
from policies.act.training import augment_change

VARIANTS = {"real": 0, "fa1": 1, "fa2": 2, "fa4": 4}

PROG = "python -m benchmarks.act"


def _observation(cameras=("third_view", "wrist"), camera_hw=(96, 128), tactile_hw=(120, 160), seed=0) -> dict:
    rng = np.random.default_rng(seed)
    obs = {LOOP_STATE: rng.normal(size=5).astype(np.float32)}
    for c in cameras:
        obs[image_key(c, LOOP)] = rng.integers(0, 256, (*camera_hw, 3), dtype=np.uint8)
    for s in ("left", "right"):
        obs[tactile_key(s, LOOP)] = rng.integers(0, 256, (*tactile_hw, 3), dtype=np.uint8)
        obs[background_key(s, LOOP)] = rng.integers(0, 256, (*tactile_hw, 3), dtype=np.uint8)
    return obs


def latency(quick: bool) -> list[dict]:
    """Median wall and CPU time of ``predict_chunk`` (batch 1, scene-sized frames) per preset."""
    from policies.act import ACT, ACTConfig, ACTPolicy

    rows = []
    for preset, repeats in (("cpu", 10 if quick else 30), ("gpu", 2 if quick else 5)):
        torch.manual_seed(0)
        model = ACT(ACTConfig.from_preset(preset))
        policy = ACTPolicy(model)
        obs = _observation()
        wall = timings(lambda: policy.predict_chunk(obs), repeats=repeats, warmup=2)
        cpu = median_time(lambda: policy.predict_chunk(obs), repeats=repeats, clock=time.process_time)
        rows.append({"preset": preset, "params_M": sum(p.numel() for p in model.parameters()) / 1e6,
                     "chunk": model.config.chunk_size, "ms_per_chunk": statistics.median(wall) * 1e3,
                     "ms_quartiles": [q * 1e3 for q in quartiles(wall)], "calls": repeats, "cpu_ms_per_chunk": cpu * 1e3,
                     "target_ms": 30.0 if preset == "cpu" else None,
                     "threads": torch.get_num_threads()})
    return rows


def training_throughput(demos: Path, quick: bool) -> dict:
    """Samples/s of one cpu-preset training step (forward + backward + AdamW) on real demo batches."""
    from torch.utils.data import DataLoader

    from controltac_il.datasets import EpisodeDataset
    from policies.act import ACT, ACTConfig

    ds = EpisodeDataset(demos, chunk_size=20)
    cfg = ACTConfig.from_preset("cpu", camera_names=tuple(ds.cameras), tactile_names=tuple(ds.tactile_sensors))
    model = ACT(cfg)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr)
    batch = next(iter(DataLoader(ds, batch_size=16, shuffle=True, generator=torch.Generator().manual_seed(0))))

    def step():
        loss = model(batch)["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()

    t = median_time(step, repeats=3 if quick else 10, warmup=1)
    cpu = median_time(step, repeats=3 if quick else 10, clock=time.process_time)
    return {"preset": "cpu", "batch_size": 16, "s_per_step": t, "samples_per_s": 16 / t,
            "cpu_s_per_step": cpu, "samples_per_cpu_s": 16 / cpu, "threads": torch.get_num_threads()}


def _trained(run: Path, steps: int) -> bool:
    return policy_meta(run).get("step", 0) >= steps


def run_variant(variant: str, *, demos: str, runs: str, steps: int, batch_size: int, eval_episodes: int,
                shifted_grip: tuple[float, float], generator: str | None, max_copies: int) -> dict:
    """Train one variant (or reuse it when trained to ``steps``) and evaluate it at the demos' grip-force
    range and at ``shifted_grip``; one torch thread, so variants can run side by side."""
    torch.set_num_threads(1)
    from controltac_il.app import evaluate_in_sim
    from controltac_il.augment import ForceAugmentStage
    from controltac_il.app.experiment import EVAL_SEED
    from policies.act.training import ACTTrainConfig, train_on_folder

    run, copies = Path(runs) / variant, VARIANTS[variant]
    row: dict = {}
    t = time.perf_counter()
    if not _trained(run, steps):
        augment = ForceAugmentStage(copies, generator, seed=0, max_copies=max_copies) if copies else None
        summary = train_on_folder(demos, run, preset="cpu", augment=augment, train_config=ACTTrainConfig(
            steps=steps, batch_size=batch_size, val_every=min(500, steps), seed=0),
            resume=(run / "last").is_dir(), progress=False)
        row.update(train_frames=summary["train_frames"], samples_per_s=summary["samples_per_s"])
    row["best_val_l1"] = json.loads((run / "best" / "config.json").read_text())["meta"]["best_val_l1"]
    row["train_s"] = time.perf_counter() - t
    for name, grip in (("nominal", None), ("shifted", tuple(shifted_grip))):
        t = time.perf_counter()
        res = evaluate_in_sim(run, episodes=eval_episodes, seed=EVAL_SEED, grip_force_range=grip, progress=False)
        row[f"{name}_success"] = res["success_rate"]
        row[f"{name}_wilson95"] = [round(x, 3) for x in res["wilson95"]]
        row[f"{name}_n"] = res["episodes"]
        row[f"{name}_grip_n"] = res["grip_force_range_n"]
        row[f"{name}_eval_s"] = time.perf_counter() - t
    row["status"] = "done"
    return row


def stale_runs(runs: Path, variants: list[str], generator: str | None) -> list[str]:
    """Why each policy under ``runs`` trained with another generator or augmentation cannot be reused
    as this run's (empty: all reusable or not trained yet)."""
    from controltac_il.augment import ForceAugmentStage

    stale = []
    for v in variants:
        try:
            now = ForceAugmentStage(VARIANTS[v], generator, seed=0).description if VARIANTS[v] else None
        except OSError:
            continue  # no generator: the variant is skipped later
        change = augment_change(policy_meta(runs / v).get("augment", now), now)
        if change:
            stale.append(f"{runs / v} was trained with different augmentation ({change})")
    return stale


def parse(argv) -> tuple:
    """The command line, its --quick sizes applied; (args, variants, parser)."""
    p = base_parser(PROG, __doc__.split("\n\n")[0])
    p.add_argument("--demos", type=int, default=50, help="demos collected in the scene (default 50, the paper's)")
    p.add_argument("--steps", type=int, default=1500, help="training steps per variant (default 1500)")
    p.add_argument("--batch-size", type=int, default=16, help="training batch size (default 16)")
    p.add_argument("--eval-episodes", type=int, default=50, help="seeded evaluation episodes per setting (default 50)")
    p.add_argument("--variants", default="real,fa1,fa2,fa4", help="comma list of real, fa1, fa2, fa4")
    p.add_argument("--shifted-grip", type=float, nargs=2, default=(10.0, 12.0), metavar=("LOW", "HIGH"),
                   help="test grip force range outside the demos' (3-9 N) (default 10 12)")
    p.add_argument("--runs", type=Path, default=Path("runs/benchmark_act"),
                   help="folder for the trained policies (reused when already trained to --steps)")
    p.add_argument("--generator", default=None, help="generator checkpoint for ForceAugment (default shipped)")
    p.add_argument("--jobs", type=int, default=1,
                   help="variants trained and evaluated at once, one process and torch thread each (default 1)")
    p.add_argument("--skip-experiment", action="store_true", help="only latency and throughput")
    args = p.parse_args(argv)
    if args.quick:
        args.demos, args.steps, args.eval_episodes = 3, 20, 2
        args.variants = "real,fa1"
        if args.runs == p.get_default("runs"):
            args.runs = Path("runs/benchmark_act_quick")
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        p.error(f"--variants: unknown {unknown}; choose from {list(VARIANTS)}")
    return args, variants, p


def main(argv=None) -> dict:
    args, variants, p = parse(argv)
    torch.set_num_threads(1)
    from controltac_il.app import default_demos

    if not args.skip_experiment:
        stale = stale_runs(args.runs, variants, args.generator)
        if stale:
            p.error(f"--runs: {stale[0]}; pass another --runs folder or remove that one")

    results: dict = {"settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}}

    def save():
        write_results(args.out, results) if args.out else None

    results["load_average_1m_at_start"] = os.getloadavg()[0]
    results["latency"] = latency(args.quick)
    print_table(results["latency"], ["preset", "params_M", "chunk", "ms_per_chunk", "cpu_ms_per_chunk", "target_ms",
                                     "threads"],
                "ACT inference latency per chunk (batch 1, 96x128 cameras, 120x160 tactile)")
    t = time.perf_counter()
    demos = default_demos(args.demos, seed=0)
    results["collect_s"] = time.perf_counter() - t
    results["training_throughput"] = training_throughput(demos, args.quick)
    print_table([results["training_throughput"]], ["preset", "batch_size", "s_per_step", "samples_per_s",
                                                   "cpu_s_per_step", "samples_per_cpu_s", "threads"],
                "ACT training throughput")
    save()
    if args.skip_experiment:
        return results
    results["experiment"] = experiment(args, variants, demos, save)
    print_table(results["experiment"], ["variant", "copies", "nominal_success", "nominal_wilson95", "shifted_success",
                                        "shifted_wilson95", "best_val_l1", "train_s"],
                f"Peg-in-hole success, {args.demos} demos, {args.eval_episodes} seeded episodes per setting")
    save()
    return results


def generator_problem(args, demos, max_copies: int) -> str | None:
    """Why the ForceAugment variants cannot run (no usable generator), or None after building their cache once,
    before any worker reads it."""
    from controltac_il.augment import ForceAugmentStage

    if not max_copies:
        return None
    try:
        from controltac_il.app.experiment import training_split
        from controltac_il.generator import ForceGenerator

        ForceGenerator.from_pretrained(args.generator)
        ForceAugmentStage(max_copies, args.generator, seed=0)(training_split(demos))
    except (OSError, ValueError, ImportError) as exc:
        print(f"ForceAugment variants skipped, no generator: {type(exc).__name__}: {exc}")
        return f"{type(exc).__name__}: {exc}"
    return None


def experiment(args, variants: list[str], demos, save) -> list[dict]:
    """Train and evaluate each variant (``--jobs`` at once); one row each, saved (``save()``) as each finishes."""
    rows: list[dict] = []
    max_copies = max(VARIANTS[v] for v in variants)
    problem = generator_problem(args, demos, max_copies)
    for v in variants:
        skipped = VARIANTS[v] and problem
        rows.append({"variant": v, "copies": VARIANTS[v],
                     "status": f"skipped (no generator: {problem})" if skipped else "queued"})
    todo = [row for row in rows if row["status"] == "queued"]
    job_args = dict(demos=str(demos), runs=str(args.runs), steps=args.steps, batch_size=args.batch_size,
                    eval_episodes=args.eval_episodes, shifted_grip=tuple(args.shifted_grip),
                    generator=args.generator, max_copies=max_copies)
    if args.jobs > 1 and len(todo) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(min(args.jobs, len(todo)), mp_context=multiprocessing.get_context("spawn")) as pool:
            # variants still to train first: they take longest
            order = sorted(todo, key=lambda row: _trained(args.runs / row["variant"], args.steps))
            futures = {pool.submit(run_variant, row["variant"], **job_args): row for row in order}
            for row in todo:
                row["status"] = "running"
            save()
            for fut in as_completed(futures):
                futures[fut].update(fut.result())
                print(f"{futures[fut]['variant']}: done")
                save()
    else:
        for row in todo:
            row["status"] = "running"
            save()
            row.update(run_variant(row["variant"], **job_args))
            save()
    return rows


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
