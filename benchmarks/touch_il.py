"""Touch-critical imitation learning: the paper's ACT experiment on the scene only touch can solve.

    python -m benchmarks.touch_il --out benchmarks/results/touch_il.json --jobs 2     # full grid
    python -m benchmarks.touch_il --out benchmarks/results/touch_il.json --jobs 2 --resume
    python -m benchmarks.touch_il --quick --out /tmp/touch_il.json                    # CI size

Scene: ``PegInHoleConfig.touch_critical()`` (the peg starts in the hand 5-8 mm off the TCP along the
gel; the cameras cannot see it). For every demonstration budget and variant one cpu-preset ACT is
trained on the first N scripted demos, then deployed through the robot's control loop on the same
seeded episodes (its final checkpoint: see CHECKPOINT_NOTE) in three grip-force bands: ``nominal`` (the demos' band) and ``shifted_low`` /
``shifted_high``. Variants: ``vision_only`` (no tactile streams), ``real`` (visuo-tactile, real demos),
``fa1`` / ``fa2`` / ``fa4`` (ForceAugment copies), ``image_aug`` (as many photometrically jittered
copies as ``--image-aug-copies``). Each cell reports successes, the Wilson 95 % interval and, for the
augmented and vision-only variants, Fisher's exact test (one-sided) against ``real`` in the same
budget and band. Every cell is written to ``RUNS/cells/`` the moment it finishes; ``--resume`` picks
up trained policies and finished cells, so an interrupted grid continues where it stopped.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

from benchmarks.common import save_figure
from controltac_il.app.experiment import EVAL_SEED

BUDGETS = (20, 35, 50)
# variant -> (augmentation kind, copies); image_aug's copies come from --image-aug-copies
VARIANTS = {"vision_only": ("none", 0), "real": ("none", 0), "fa1": ("force", 1), "fa2": ("force", 2),
            "fa4": ("force", 4), "image_aug": ("image", None)}
SETTINGS = ("nominal", "shifted_low", "shifted_high")
SHIFTED_LOW_N = (1.5, 3.0)
SHIFTED_HIGH_N = (8.0, 10.0)
CHECKPOINT_NOTE = ("policies are evaluated at their final step: the held-out L1 that picks best/ is blind to the "
                   "few-mm lateral correction touch supplies (real, 50 demos: best/ = step 1000 succeeded 17/50, "
                   "last/ = step 2000 28/30 on the same seeds)")

PROG = "python -m benchmarks.touch_il"


def fisher_greater(k_a: int, n_a: int, k_b: int, n_b: int) -> float:
    """One-sided Fisher exact p-value that A's success rate exceeds B's."""
    from scipy.stats import fisher_exact

    return float(fisher_exact([[k_a, n_a - k_a], [k_b, n_b - k_b]], alternative="greater").pvalue)


def add_p_values(cells: list[dict]) -> None:
    """``p_vs_real``: for each non-real cell, P(one-sided Fisher) that it beats ``real`` in the same budget
    and setting (``vision_only``: that ``real`` beats it); None without the matching real cell."""
    real = {(c["demos"], c["setting"]): c for c in cells if c["variant"] == "real"}
    for c in cells:
        r = real.get((c["demos"], c["setting"]))
        if c["variant"] == "real" or r is None:
            c["p_vs_real"] = None
        elif c["variant"] == "vision_only":
            c["p_vs_real"] = fisher_greater(r["successes"], r["episodes"], c["successes"], c["episodes"])
        else:
            c["p_vs_real"] = fisher_greater(c["successes"], c["episodes"], r["successes"], r["episodes"])


def budget_demos(all_demos: Path, runs: Path, n: int) -> Path:
    """Folder holding links to the first ``n`` episodes of ``all_demos`` (a budget is a prefix)."""
    from controltac_il.datasets import episode_paths

    paths = episode_paths(all_demos)[:n]
    folder = runs / f"demos-n{n}"
    folder.mkdir(parents=True, exist_ok=True)
    for i, p in enumerate(paths):
        link = folder / f"episode_{i}.hdf5"
        if not link.exists():
            link.symlink_to(p.resolve())
    return folder


def make_stage(variant: str, copies: int, generator: str | None, max_force_copies: int,
               force_settings: dict | None = None):
    """The training set's augmentation for a variant (None for real and vision_only); force_settings:
    ForceAugment fields that differ from the paper's (``offset_range``, ``out_of_range``)."""
    kind, _ = VARIANTS[variant]
    if kind == "force":
        from controltac_il.augment import ForceAugmentStage

        return ForceAugmentStage(copies, generator, seed=0, max_copies=max_force_copies, **(force_settings or {}))
    if kind == "image":
        from controltac_il.datasets.photometric import PhotometricAugmentStage

        return PhotometricAugmentStage(copies, seed=0)
    return None


def _cell_path(runs: Path, variant: str, demos: int, setting: str) -> Path:
    return runs / "cells" / f"{variant}-n{demos}-{setting}.json"


def load_cells(runs: Path, signature: str) -> dict[tuple, dict]:
    """Finished cells under ``runs/cells`` whose settings signature matches (others are not this grid's)."""
    out = {}
    for path in sorted((runs / "cells").glob("*.json")):
        cell = json.loads(path.read_text())
        if cell.get("signature") == signature:
            out[(cell["variant"], cell["demos"], cell["setting"])] = cell
    return out


def run_unit(variant: str, demos: int, *, demos_dir: str, runs: str, steps: int, batch_size: int, copies: int,
             generator: str | None, max_force_copies: int, bands: dict, eval_episodes: int, signature: str,
             todo_settings: list[str], eval_seed: int, force_settings: dict | None = None,
             train_seed: int = 0) -> list[dict]:
    """Train one (variant, budget) policy, or reuse it when trained to ``steps``, then evaluate it in
    each setting of ``todo_settings``; each cell is written to ``runs/cells`` as soon as it is done.
    One torch thread, so two units can run side by side on 2 cores."""
    import torch

    torch.set_num_threads(1)
    from controltac_il.app import evaluate_in_sim
    from controltac_il.app.experiment import policy_meta, train_policy
    from controltac_il.io import write_json
    from controltac_il.metrics import wilson_interval

    runs = Path(runs)
    run = runs / "policies" / f"{variant}-n{demos}"
    trained_now = policy_meta(run).get("step", 0) < steps
    train_s = train_policy(demos_dir, run, steps=steps, batch_size=batch_size, seed=train_seed,
                           augment=make_stage(variant, copies, generator, max_force_copies, force_settings),
                           vision_only=variant == "vision_only")
    meta = policy_meta(run)
    best = json.loads((run / "best" / "config.json").read_text())["meta"]
    cells = []
    for setting in todo_settings:
        t = time.perf_counter()
        # an episode that raised is never a failure: EvaluationError stops the grid naming the cell, nothing written
        res = evaluate_in_sim(run / "last", episodes=eval_episodes, seed=eval_seed, grip_force_range=bands[setting],
                              scene="touch_critical", progress=False, label=f"cell {variant}-n{demos}-{setting}")
        lo, hi = wilson_interval(res["successes"], res["episodes"])
        cell = {"variant": variant, "demos": demos, "copies": copies, "setting": setting,
                "grip_n": list(bands[setting]), "successes": res["successes"], "episodes": res["episodes"],
                "success_rate": res["success_rate"], "wilson95": [round(lo, 4), round(hi, 4)],
                "errors": res["errors"], "eval_s": round(time.perf_counter() - t, 1),
                "train_s": round(train_s, 1) if trained_now else None,
                "train_frames": meta.get("train_frames"), "train_steps": meta.get("step"),
                "checkpoint": "last", "best_val_l1": best.get("best_val_l1"), "best_step": best.get("step"),
                "augment": meta.get("augment"),
                "inference_ms_p50": res["inference_ms_p50"], "signature": signature}
        write_json(_cell_path(runs, variant, demos, setting), cell)
        cells.append(cell)
    return cells


def plot(cells: list[dict], path: Path, budgets: list[int], image_aug_copies: int) -> None:
    """Success vs ForceAugment copies per budget (lines) and setting (panels), Wilson 95 % bars;
    vision_only and image_aug as separate markers (the paper's figure, plus the controls)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(SETTINGS), figsize=(4.2 * len(SETTINGS), 3.6), sharey=True)
    colours = dict(zip(budgets, plt.cm.viridis([0.15 + 0.7 * i / max(len(budgets) - 1, 1) for i in range(len(budgets))])))
    by = {(c["variant"], c["demos"], c["setting"]): c for c in cells}
    for ax, setting in zip(axes, SETTINGS):
        for n in budgets:
            pts = [(VARIANTS[v][1], by[(v, n, setting)]) for v in ("real", "fa1", "fa2", "fa4")
                   if (v, n, setting) in by]
            if pts:
                x = [p[0] for p in pts]
                y = [p[1]["success_rate"] for p in pts]
                err = [[p[1]["success_rate"] - p[1]["wilson95"][0] for p in pts],
                       [p[1]["wilson95"][1] - p[1]["success_rate"] for p in pts]]
                ax.errorbar(x, y, yerr=err, marker="o", capsize=3, color=colours[n], label=f"{n} demos: real → FA")
            for v, marker, dx in (("vision_only", "x", -0.25), ("image_aug", "s", 0.0)):
                c = by.get((v, n, setting))
                if c is not None:
                    xv = image_aug_copies if v == "image_aug" else 0
                    ax.errorbar([xv + dx], [c["success_rate"]],
                                yerr=[[c["success_rate"] - c["wilson95"][0]], [c["wilson95"][1] - c["success_rate"]]],
                                marker=marker, linestyle="none", capsize=2, color=colours[n], alpha=0.6,
                                label=f"{n} demos: {v}")
        grip = next((c["grip_n"] for c in cells if c["setting"] == setting), None)
        ax.set_title(f"{setting} (grip {grip[0]:g}-{grip[1]:g} N)" if grip else setting)
        ax.set_xlabel("augmented copies per demo")
        ax.set_xticks([0, 1, 2, 4])
        ax.set_ylim(-0.03, 1.03)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("success rate (Wilson 95 %)")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=7, frameon=False)
    fig.tight_layout(rect=(0, 0.16, 1, 1))
    save_figure(fig, path, dpi=110)


def _band(p, flag: str, value) -> tuple[float, float]:
    lo, hi = (float(v) for v in value)
    if not lo < hi:
        p.error(f"{flag}: empty grip band {lo:g}-{hi:g} N (low must be below high)")
    if lo < 0.5 or hi > 15.0:
        p.error(f"{flag}: {lo:g}-{hi:g} N is outside the finger servo's range 0.5-15 N")
    return lo, hi


def parser():
    """The command line's options (``parse_args`` checks them together)."""
    from benchmarks.common import base_parser

    p = base_parser(PROG, __doc__.split("\n\n")[0])
    p.add_argument("--demos", default=",".join(map(str, BUDGETS)),
                   help="comma list of demonstration budgets (default 20,35,50; each <= --collect)")
    p.add_argument("--collect", type=int, default=max(BUDGETS),
                   help=f"scripted demos collected once; budgets are its first N (default {max(BUDGETS)})")
    p.add_argument("--variants", default=",".join(VARIANTS), help=f"comma list of {', '.join(VARIANTS)}")
    p.add_argument("--image-aug-copies", type=int, default=2,
                   help="photometric copies for image_aug, to compare with the fa variant of as many (default 2)")
    p.add_argument("--steps", type=int, default=2000, help="ACT training steps per policy (default 2000)")
    p.add_argument("--batch-size", type=int, default=16, help="training batch size (default 16)")
    p.add_argument("--eval-episodes", type=int, default=50, help="seeded evaluation episodes per cell (default 50)")
    p.add_argument("--eval-seed", type=int, default=EVAL_SEED,
                   help=f"first evaluation scene seed (default {EVAL_SEED}, envs.config.EVAL_SEED; the committed "
                        "grid in benchmarks/results/touch_il.json ran with 200000)")
    p.add_argument("--nominal-grip", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
                   help="the demos' grip band in N (default: the scene's, 4 7)")
    p.add_argument("--shifted-low", type=float, nargs=2, default=SHIFTED_LOW_N, metavar=("LOW", "HIGH"),
                   help="grip band below the demos' in N (default 1.5 3)")
    p.add_argument("--shifted-high", type=float, nargs=2, default=SHIFTED_HIGH_N, metavar=("LOW", "HIGH"),
                   help="grip band above the demos' in N (default 8 10)")
    p.add_argument("--generator", default=None, help="generator checkpoint for ForceAugment (default: shipped)")
    p.add_argument("--offset-range", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
                   help="ForceAugment's per-copy normal-force offset range in N (default: the paper's -3 10)")
    p.add_argument("--out-of-range", default=None, choices=("clamp", "skip"),
                   help="ForceAugment targets outside Fz 1-10 N: clamp them (default) or keep the frame real")
    p.add_argument("--runs", type=Path, default=Path("runs/touch_il"),
                   help="folder for demos, policies and finished cells (default runs/touch_il)")
    p.add_argument("--train-seed", type=int, default=0,
                   help="seed of the policies' initialisation and sampling order (default 0); the demos, their "
                        "train/validation split and the ForceAugment draws stay fixed, so seeds measure training variance")
    p.add_argument("--jobs", type=int, default=1, help="policies trained and evaluated at once (default 1; 2 on 2 cores)")
    p.add_argument("--resume", action="store_true",
                   help="continue a grid in --runs: reuse its trained policies and finished cells")
    return p


def parse_args(argv=None):
    """(parser, args): the options checked, --quick's sizes applied, the budgets, variants and grip bands parsed."""
    p = parser()
    args = p.parse_args(argv)
    args.force_settings = {k: v for k, v in (("offset_range", args.offset_range), ("out_of_range", args.out_of_range))
                           if v is not None}
    if args.offset_range is not None and not args.offset_range[0] <= args.offset_range[1]:
        p.error(f"--offset-range: low {args.offset_range[0]:g} N is above high {args.offset_range[1]:g} N")
    if args.quick:
        args.demos, args.collect, args.steps, args.eval_episodes = "3", 3, 4, 1
        args.variants, args.image_aug_copies, args.batch_size = "vision_only,real,fa1,image_aug", 1, 4
        if args.runs == p.get_default("runs"):
            args.runs = Path("runs/touch_il_quick")
    try:
        args.budgets = sorted({int(v) for v in args.demos.split(",") if v.strip()})
    except ValueError:
        p.error(f"--demos: expected a comma list of integers, got {args.demos!r}")
    if not args.budgets or args.budgets[0] < 2:
        p.error(f"--demos: every budget must be >= 2 (one episode is held out for validation), got {args.demos!r}")
    if args.budgets[-1] > args.collect:
        p.error(f"--demos: budget {args.budgets[-1]} is larger than the {args.collect} collected demos (--collect)")
    args.variant_list = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in args.variant_list if v not in VARIANTS]
    if unknown or not args.variant_list:
        p.error(f"--variants: unknown {unknown or args.variants!r}; choose from {', '.join(VARIANTS)}")
    for name in ("steps", "batch_size", "eval_episodes", "jobs", "image_aug_copies"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    from controltac_il.app.experiment import touch_scene

    nominal = args.nominal_grip or touch_scene().grip_force_range_n
    args.bands = {"nominal": _band(p, "--nominal-grip", nominal),
                  "shifted_low": _band(p, "--shifted-low", args.shifted_low),
                  "shifted_high": _band(p, "--shifted-high", args.shifted_high)}
    if not args.bands["shifted_low"][1] <= args.bands["nominal"][0]:
        p.error(f"--shifted-low: {args.bands['shifted_low']} must lie below the nominal band {args.bands['nominal']}")
    if not args.bands["shifted_high"][0] >= args.bands["nominal"][1]:
        p.error(f"--shifted-high: {args.bands['shifted_high']} must lie above the nominal band {args.bands['nominal']}")
    return p, args


def signature_of(args, generator_hash: str | None) -> str:
    """The grid's settings hashed: cells of a grid with other training or evaluation settings are never mixed."""
    from controltac_il.app.experiment import touch_scene

    sig_fields = {"scene": "touch_critical", "scene_config": repr(touch_scene()),
                  "steps": args.steps, "batch_size": args.batch_size, "eval_episodes": args.eval_episodes,
                  "eval_seed": args.eval_seed, "bands": args.bands, "generator_hash": generator_hash,
                  "collect": args.collect, "image_aug_copies": args.image_aug_copies, "checkpoint": "last",
                  **({"force_settings": args.force_settings} if args.force_settings else {}),
                  **({"train_seed": args.train_seed} if args.train_seed else {})}
    return hashlib.sha1(json.dumps(sig_fields, sort_keys=True, default=str).encode()).hexdigest()[:12]


def settings_of(args, copies: dict, generator_hash: str | None, signature: str) -> dict:
    """The JSON's record of the grid's settings."""
    return {"scene": "PegInHoleConfig.touch_critical()", "budgets": args.budgets, "variants": args.variant_list,
            "copies": copies, "train_seed": args.train_seed, "steps": args.steps, "batch_size": args.batch_size,
            "eval_episodes": args.eval_episodes, "eval_seed": args.eval_seed, "grip_bands_n": args.bands,
            "collect": args.collect, "generator": args.generator, "generator_hash": generator_hash,
            "jobs": args.jobs, "signature": signature,
            "force_augment": args.force_settings or "paper: offset U[-3, 10] N, jitter {0, ±0.5, ±1} N, clamp",
            "checkpoint": CHECKPOINT_NOTE}


def prepare(p, args, results: dict, copies: dict, max_force: int) -> dict:
    """Collect the demos, write each budget's folder and ForceAugment cache (once, before any worker reads it) and
    refuse a policy in --runs trained with other augmentation; {budget: demos folder}."""
    from controltac_il.app import default_demos
    from controltac_il.app.experiment import augment_change, policy_meta, training_split

    t = time.perf_counter()
    all_demos = default_demos(args.collect, seed=0, scene="touch_critical")
    results["collect_s"] = round(time.perf_counter() - t, 1)
    dirs = {n: budget_demos(all_demos, args.runs, n) for n in args.budgets}
    for n in args.budgets:
        if max_force:
            t = time.perf_counter()
            make_stage("fa1", 1, args.generator, max_force, args.force_settings)(training_split(dirs[n]))
            results.setdefault("cache_s", {})[str(n)] = round(time.perf_counter() - t, 1)
    for v in args.variant_list:
        stage = make_stage(v, copies[v], args.generator, max_force, args.force_settings)
        for n in args.budgets:
            run = args.runs / "policies" / f"{v}-n{n}"
            meta = policy_meta(run)
            change = augment_change(meta.get("augment"), stage.description if stage else None)
            if meta and change:
                p.error(f"--runs: {run} was trained with different augmentation ({change}); use another --runs folder")
    return dirs


def run_units(units: list, jobs: int, dirs: dict, copies: dict, job: dict, cells: list, save) -> None:
    """Train and evaluate each (variant, budget, settings to do), ``jobs`` at once; ``save(cells)`` after each."""
    from tqdm import tqdm

    bar = tqdm(total=len(units), desc="policies", unit="policy", dynamic_ncols=True, disable=None)
    if jobs > 1 and len(units) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(min(jobs, len(units)), mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = {pool.submit(run_unit, v, n, demos_dir=str(dirs[n]), copies=copies[v], todo_settings=todo, **job):
                       (v, n) for v, n, todo in units}
            for fut in as_completed(futures):
                cells.extend(fut.result())
                save(cells)
                bar.update(1)
    else:
        for v, n, todo in units:
            cells.extend(run_unit(v, n, demos_dir=str(dirs[n]), copies=copies[v], todo_settings=todo, **job))
            save(cells)
            bar.update(1)
    bar.close()


def main(argv=None) -> dict:
    p, args = parse_args(argv)
    import torch

    from benchmarks.common import print_table, write_results
    from controltac_il.app.touch_probes import grip_response, vision_check
    from controltac_il.io import write_json

    torch.set_num_threads(2 if args.jobs == 1 else 1)
    t_start = time.perf_counter()
    copies = {v: (args.image_aug_copies if VARIANTS[v][0] == "image" else VARIANTS[v][1]) for v in args.variant_list}
    max_force = max([copies[v] for v in args.variant_list if VARIANTS[v][0] == "force"], default=0)
    generator_hash = None
    if max_force:
        from controltac_il.generator.checkpoint import checkpoint_hash
        from controltac_il.generator.shipped import locate_checkpoint

        generator_hash = checkpoint_hash(locate_checkpoint(args.generator))
    signature = signature_of(args, generator_hash)
    done = load_cells(args.runs, signature) if (args.runs / "cells").is_dir() else {}
    if (args.runs / "cells").is_dir() and any((args.runs / "cells").iterdir()) and not args.resume:
        p.error(f"--runs: {args.runs} already holds a grid; pass --resume to continue it or another --runs folder")
    results: dict = {"benchmark": "touch_il", "settings": settings_of(args, copies, generator_hash, signature)}
    history_path = args.runs / "wall_s.json"
    history = json.loads(history_path.read_text()) if args.resume and history_path.is_file() else []

    def save(cells, picture: bool = False):
        """Cells as they finish (JSON, atomic); the picture (3-4 s of matplotlib) once, at the end."""
        add_p_values(cells)
        results["cells"] = sorted(cells, key=lambda c: (c["demos"], list(VARIANTS).index(c["variant"]),
                                                         SETTINGS.index(c["setting"])))
        results["wall_s"] = {"this_invocation": round(time.perf_counter() - t_start, 1),
                             "earlier_invocations": history, "total": round(sum(history) + time.perf_counter() - t_start, 1)}
        if args.out:
            write_results(args.out, results)
            if picture and results["cells"]:
                plot(results["cells"], args.out.with_suffix(".png"), args.budgets, args.image_aug_copies)

    results["vision_check"] = vision_check(range(3 if args.quick else 20))
    results["grip_response"] = grip_response(args.bands, range(3 if args.quick else 12), args.generator)
    dirs = prepare(p, args, results, copies, max_force)
    cells = list(done.values())
    save(cells)
    # largest budget first: the paper's headline (50 demos) finishes first
    units = [(v, n, todo) for n in sorted(args.budgets, reverse=True) for v in args.variant_list
             if (todo := [s for s in SETTINGS if (v, n, s) not in done])]
    job = dict(runs=str(args.runs), eval_seed=args.eval_seed, steps=args.steps, batch_size=args.batch_size,
               generator=args.generator, max_force_copies=max_force, bands=args.bands,
               eval_episodes=args.eval_episodes, signature=signature, force_settings=args.force_settings,
               train_seed=args.train_seed)
    run_units(units, args.jobs, dirs, copies, job, cells, save)
    write_json(history_path, history + [round(time.perf_counter() - t_start, 1)])
    save(cells, picture=True)
    print_table(results["cells"], ["variant", "demos", "copies", "setting", "successes", "episodes", "wilson95",
                                   "p_vs_real", "best_val_l1"],
                f"Touch-critical peg-in-hole, {args.eval_episodes} seeded episodes per cell")
    return results


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
