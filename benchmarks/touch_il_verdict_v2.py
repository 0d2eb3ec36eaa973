"""The verdict, second run: enough paired seeds to decide at the seed level, each variant at its own validated
checkpoint, and an augmentation that reaches the shifts it is tested on (issue 38).

    python -m benchmarks.touch_il_verdict_v2 --out benchmarks/results/touch_il_verdict_v2.json --jobs 2
    python -m benchmarks.touch_il_verdict_v2 --out benchmarks/results/touch_il_verdict_v2.json --jobs 2 --resume
    python -m benchmarks.touch_il_verdict_v2 --quick --allow-underpowered --out /tmp/v2.json   # CI size

PROTOCOL v2 (committed before any of its results existed; the JSON's ``protocol`` repeats it)

Why a second run: v1 (``touch_il_verdict.json``, kept as history) had 5 seeds (a sign-flip test cannot go below
p = 0.0625), reported episode-level CMH p values (the wrong unit for a recipe), held every variant to a step tuned
on ``real`` alone, and drew the paper's offsets U[-3, 10] N, which clamp 43 % of contact frames at 10 N and barely
reach below the demos' 4-7 N grip.

1. Seeds. 12 paired training seeds (0-11), pre-registered; never more or fewer after a result is seen. Demos:
   scene seeds [0, 50) (scripted expert, as v1). Validation episodes [700000, 700030); test episodes
   [900000, 900050), never looked at before (v1 tested at 800000, earlier grids at 100000 and 200000).
   Power, from v1's seed-level spread (pooled SD 0.253 of the paired per-seed differences of fa2, fa4 and
   image_aug against real; ``verdict_report.sign_flip_mde``): with 12 seeds the exact sign-flip test detects a
   mean paired difference of 31 points at Holm's strictest step (alpha 0.05 / 6) and of 23 points at alpha 0.05,
   each with 80 % power (10 seeds: 37 and 26). Smaller effects may go undetected.
   Compute: 48 policies of 6000 steps and 330 episodes each, estimated 10-12 h on 2 cores (--jobs 2), over
   several sessions with --resume.
2. Variants (``vision_only`` dropped: v1 settled it, -48 points at nominal with every seed below real):
   ``real``; ``fa2``: 2 ForceAugment copies, the paper's offsets U[-3, 10] N and jitter {0, +-0.5, +-1} N, clamped
   to Fz 1-10 N; ``fa2_range``: the same 2 copies with each copy's offset drawn so that its targets spread over the
   validated range (``target_range`` (1, 10): offset = U[1, 10] - the episode's median contact Fz), jitter,
   clamped; ``image_aug``: 2 photometric copies (the control). Every ForceAugment uses the shipped generator. Each
   fa variant's clamped fraction and the histogram of its requested and used target forces are reported.
3. Checkpoint per variant, on validation only. Every (variant, seed) trains to 6000 steps (cpu preset, batch 16,
   AdamW 3e-4, 50 warm-up steps then constant, demos split seed 0) with snapshots every 1000 steps; each snapshot
   runs the validation episodes at nominal grip. Rule: each variant's step is the snapshot with the highest mean
   validation success over its seeds (ties: fewer steps); every seed of that variant is tested at that step.
   Test episodes are never used to choose.
4. Settings: ``nominal`` (the demos' 4-7 N), ``grip_0.8-1.5`` (below the demos') and ``grip_11-14``, a stress test:
   beyond the generator's validated 10 N, so no augmentation can show it.
5. Statistics at the seed level (``verdict_report``). Per comparison with real: the mean of the seed-paired
   differences with a two-level bootstrap 95 % interval (seeds, then episodes); the exact sign-flip p over seeds
   (primary) and a paired t-test p beside it. Holm over the 6 primary comparisons only: fa2 and fa2_range vs real
   in each setting. Verdict: "helps" / "hurts" when Holm's p < 0.05 (the sign of the mean difference), else "no
   detectable effect", with the effect size. image_aug vs real and episode-level CMH are secondary (no Holm, no
   verdict). Spread per variant and setting: the SD of per-seed success and the fraction of seeds below real's worst.
6. Each (variant, seed) policy runs the 50 test episodes in every setting through
   ``controltac_il.app.evaluate_in_sim`` (the robot's control loop on the simulated robot). An episode that raises
   is never counted: the unit is written to ``RUNS/failed/`` and the grid stops with one line naming it.

Every unit is saved the moment it finishes (``RUNS/units/``, ``--out``); ``--resume`` continues, and a resumed
ACT run is bit-identical to an uninterrupted one (``controltac_il.training.StepBatches`` / ``seed_update``).
"""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks.touch_il_verdict import (WallTime, _int_list, _load_done, _protocol_commit, _range, _run, _variants,
                                         saver, signature_of)

DEMO_SEEDS = (0, 50)
VALIDATION_SEEDS = (700_000, 700_030)
TEST_SEEDS = (900_000, 900_050)
LOOKED_AT = {"v1 test": (800_000, 800_050), "touch_il test": (200_000, 200_050), "earlier test": (100_000, 100_050)}
TRAIN_SEEDS = tuple(range(12))
MIN_SEEDS = 10
VARIANTS = ("real", "fa2", "fa2_range", "image_aug")
PRIMARY = ("fa2", "fa2_range")
FORCE_SETTINGS = {"fa2": {}, "fa2_range": {"target_range": (1.0, 10.0)}}
COPIES = {"fa2": 2, "fa2_range": 2, "image_aug": 2}
SNAPSHOTS = (1000, 2000, 3000, 4000, 5000, 6000)
SETTINGS = {"nominal": (4.0, 7.0), "grip_0.8-1.5": (0.8, 1.5), "grip_11-14": (11.0, 14.0)}
STRESS = "grip_11-14"
BATCH_SIZE = 16
DEMOS = 50
V1_PAIRED_SD = 0.253  # pooled SD of v1's per-seed paired differences (fa2, fa4, image_aug vs real, 3 settings)


def power(n: int) -> dict:
    """The design's minimum detectable effects (80 % power) from v1's spread, for ``n`` seeds."""
    from benchmarks.verdict_report import sign_flip_mde

    k = len(PRIMARY) * len(SETTINGS)
    return {"seeds": n, "v1_paired_sd": V1_PAIRED_SD, "primary_comparisons": k, "power": 0.8,
            "mde_holm_first": sign_flip_mde(V1_PAIRED_SD, n, 0.05 / k), "mde_alpha": sign_flip_mde(V1_PAIRED_SD, n, 0.05),
            "statement": f"with {n} seeds the exact sign-flip test detects, with 80 % power, a mean paired difference "
                         f"of {{mde_holm_first:.0%}} at Holm's strictest step (alpha 0.05/{k}) and of {{mde_alpha:.0%}} "
                         "at alpha 0.05 (Normal per-seed differences with v1's SD 0.253)"}


def protocol_of(args) -> dict:
    """Everything that fixes the experiment (hashed into ``signature``; a resumed grid must match it)."""
    from controltac_il.app.experiment import touch_scene

    p = power(len(args.seeds))
    p["statement"] = p["statement"].format(**p)
    return {"version": 2, "demo_seeds": list(args.demo_seeds), "validation_seeds": list(args.validation_seeds),
            "test_seeds": list(args.test_seeds), "train_seeds": list(args.seeds), "demos": args.demos,
            "variants": list(args.variants), "copies": {v: COPIES.get(v, 0) for v in args.variants},
            "force_settings": {v: {k: list(x) for k, x in s.items()} for v, s in FORCE_SETTINGS.items()},
            "recipe": {"preset": "cpu", "batch_size": args.batch_size, "lr": "3e-4 (preset), 50 warm-up steps, constant",
                       "split_seed": 0, "snapshots": list(args.snapshots)},
            "checkpoint_rule": "per variant: the snapshot with the highest mean validation success over its seeds "
                               "(ties: fewer steps); all its seeds tested there",
            "settings": {k: list(v) for k, v in SETTINGS.items()}, "stress_test": STRESS,
            "statistics": "seed level: paired mean difference, two-level bootstrap 95 % CI, exact sign-flip p "
                          "(primary) and paired t p; Holm over fa2 and fa2_range vs real in each setting; "
                          "image_aug and CMH secondary",
            "power": p, "scene": "PegInHoleConfig.touch_critical()", "scene_config": repr(touch_scene())}


# --- units: one (variant, seed) trained and validated, then tested; each saved as it finishes --------------------
def make_stage(variant: str):
    """The training set's augmentation of a variant (None for real)."""
    from benchmarks.touch_il import make_stage as stage

    if variant not in COPIES:
        return None
    kind = "image_aug" if variant == "image_aug" else "fa2"
    return stage(kind, COPIES[variant], None, COPIES[variant], FORCE_SETTINGS.get(variant))


def _evaluate(checkpoint: Path, seeds: tuple[int, int], grip, where: str) -> list[int]:
    """0/1 per episode; an episode that raised stops the unit (``EvaluationError`` naming ``where``), never a 0."""
    from controltac_il.app import evaluate_in_sim

    res = evaluate_in_sim(checkpoint, episodes=seeds[1] - seeds[0], seed=seeds[0], grip_force_range=tuple(grip),
                          scene="touch_critical", progress=False, label=where)
    return [int(o["success"]) for o in res["outcomes"]]


def run_unit(unit: dict, ctx: dict) -> dict:
    """Run one unit (``train``: train to the last snapshot and validate each; ``test``: the chosen step in every
    setting) and write it to ``RUNS/units/<id>.json``; a unit whose evaluation raised goes to ``RUNS/failed/``."""
    import torch

    torch.set_num_threads(1)
    from controltac_il.app import EvaluationError
    from controltac_il.app.experiment import snapshot_path, train_policy
    from controltac_il.io import write_json

    runs, v, seed = Path(ctx["runs"]), unit["variant"], unit["seed"]
    run, out = runs / "policies" / f"{v}-s{seed}", dict(unit)
    try:
        if unit["kind"] == "train":
            snaps = ctx["snapshots"]
            out["train_s"] = train_policy(ctx["demos_dir"], run, steps=snaps[-1], batch_size=ctx["batch_size"],
                                          seed=seed, augment=make_stage(v), snapshot_every=snaps[0])
            out["validation"] = {str(s): _evaluate(snapshot_path(run, s), ctx["validation_seeds"], ctx["nominal"],
                                                   f"unit {unit['id']} (validation, step {s})") for s in snaps}
        else:
            ckpt = snapshot_path(run, unit["step"])
            out["test"] = {name: _evaluate(ckpt, ctx["test_seeds"], band, f"unit {unit['id']} ({name})")
                           for name, band in ctx["settings"].items()}
            out["errors"] = {name: [] for name in ctx["settings"]}
    except EvaluationError as exc:
        write_json(runs / "failed" / f"{unit['id']}.json", {**unit, "error": str(exc), "errors": exc.result["errors"],
                                                             "signature": ctx["signature"]})
        raise
    out["signature"] = ctx["signature"]
    write_json(runs / "units" / f"{unit['id']}.json", out)
    return out


def choose_step(train_units: list[dict], snapshots) -> dict:
    """The checkpoint rule (protocol point 3) on one variant's validation results."""
    import numpy as np

    curve = {s: [float(np.mean(u["validation"][str(s)])) for u in sorted(train_units, key=lambda u: u["seed"])]
             for s in snapshots}
    step = max(snapshots, key=lambda s: (np.mean(curve[s]), -s))
    return {"step": step, "curve": {str(s): {"rates": r, "mean": float(np.mean(r))} for s, r in curve.items()}}


def augment_counts(demos_dir: Path, variants) -> dict:
    """Build each fa variant's ForceAugment cache (before any worker reads it); per variant its summary, clamped
    fraction of contact frames, and histograms (1 N bins, 0-16 N) of the requested and used target Fz."""
    import numpy as np

    from controltac_il.app.experiment import training_split

    train, out = training_split(demos_dir), {}
    for v in (x for x in variants if x in FORCE_SETTINGS):
        aug = make_stage(v)(train)
        records = [r for r in aug.dataset.provenance() if r["reference_force"] is not None]
        asked = np.array([r["reference_force"][2] + r["offset"] + r["jitter"] for r in records])
        used = np.array([r["target_force"][2] for r in records])
        edges = np.arange(0.0, 17.0)
        contact = aug.summary["tactile_frames"] - aug.summary["no_contact"]
        out[v] = {**aug.summary, "clamped_fraction_of_contact": round(aug.summary["clamped"] / contact, 4) if contact else 0.0,
                  "fz_bins_n": edges.tolist(), "requested_fz_hist": np.histogram(np.clip(asked, 0, 16.99), edges)[0].tolist(),
                  "used_fz_hist": np.histogram(np.clip(used, 0, 16.99), edges)[0].tolist(),
                  "requested_fz_quantiles": np.quantile(asked, [0.05, 0.5, 0.95]).round(2).tolist() if asked.size else []}
    return out


# --- command line ------------------------------------------------------------------------------------------------
def parse_args(argv=None):
    from benchmarks.common import base_parser

    p = base_parser(__doc__.split("\n\n")[0])
    p.add_argument("--variants", default=",".join(VARIANTS), help=f"comma list of {', '.join(VARIANTS)} (real is required)")
    p.add_argument("--seeds", default=",".join(map(str, TRAIN_SEEDS)),
                   help=f"training seeds, the same for every variant (the protocol: 0-11; >= {MIN_SEEDS})")
    p.add_argument("--allow-underpowered", action="store_true", help=f"accept fewer than {MIN_SEEDS} seeds (tests only)")
    p.add_argument("--demos", type=int, default=DEMOS, help=f"demonstrations per policy (default {DEMOS})")
    p.add_argument("--validation-seeds", type=int, nargs=2, default=VALIDATION_SEEDS, metavar=("START", "STOP"))
    p.add_argument("--test-seeds", type=int, nargs=2, default=TEST_SEEDS, metavar=("START", "STOP"))
    p.add_argument("--snapshots", default=",".join(map(str, SNAPSHOTS)), help="validated steps; the last is the length")
    p.add_argument("--batch-size", type=int, default=BATCH_SIZE, help=f"training batch (default {BATCH_SIZE})")
    p.add_argument("--runs", type=Path, default=Path("runs/touch_il_verdict_v2"), help="policies and finished units")
    p.add_argument("--jobs", type=int, default=1, help="units at once (2 on 2 cores)")
    p.add_argument("--resume", action="store_true", help="continue the grid in --runs (and the rows in --out)")
    args = p.parse_args(argv)
    if args.quick:  # a smoke run: 2 seeds, underpowered by design
        args.demos, args.snapshots, args.batch_size, args.allow_underpowered = 3, "2,4", 4, True
        args.seeds = "0,1" if args.seeds == p.get_default("seeds") else args.seeds
        args.validation_seeds, args.test_seeds = (700_000, 700_001), (900_000, 900_002)
        if args.runs == p.get_default("runs"):
            args.runs = Path("runs/touch_il_verdict_v2_quick")
    args.variants = _variants(p, args.variants, VARIANTS)
    args.seeds = _int_list(p, "--seeds", args.seeds)
    if len(args.seeds) < MIN_SEEDS and not args.allow_underpowered:
        p.error(f"--seeds: {len(args.seeds)} seeds cannot decide at the seed level (the protocol needs >= {MIN_SEEDS}); "
                "pass --allow-underpowered for a smoke run")
    if len(args.seeds) < 2:
        p.error("--seeds: at least 2 seeds are needed for any comparison")
    args.snapshots = sorted(_int_list(p, "--snapshots", args.snapshots))
    if args.snapshots[0] < 1 or any(s % args.snapshots[0] for s in args.snapshots):
        p.error(f"--snapshots: every step must be a positive multiple of the first, got {args.snapshots}")
    if not 2 <= args.demos <= DEMO_SEEDS[1]:
        p.error(f"--demos: {args.demos} is not within 2..{DEMO_SEEDS[1]}")
    args.demo_seeds = DEMO_SEEDS
    args.validation_seeds = _range(p, "--validation-seeds", args.validation_seeds)
    args.test_seeds = _range(p, "--test-seeds", args.test_seeds)
    taken = {"demos": DEMO_SEEDS, **LOOKED_AT}
    for flag, rng in (("--validation-seeds", args.validation_seeds), ("--test-seeds", args.test_seeds)):
        for name, other in {**taken, **({"--validation-seeds": args.validation_seeds} if flag == "--test-seeds" else {})}.items():
            if rng[0] < other[1] and other[0] < rng[1]:
                p.error(f"{flag}: [{rng[0]}, {rng[1]}) overlaps the {name} seeds [{other[0]}, {other[1]})")
    for name in ("jobs", "batch_size"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    return p, args


# --- the grid -----------------------------------------------------------------------------------------------------
def main(argv=None) -> dict:
    p, args = parse_args(argv)
    import torch

    from benchmarks.common import print_table
    from benchmarks.touch_il import budget_demos
    from controltac_il.app import default_demos
    from controltac_il.io import write_json

    torch.set_num_threads(2 if args.jobs == 1 else 1)
    protocol = protocol_of(args)
    signature = signature_of(protocol)
    done = _load_done(args, p, signature)
    write_json(args.runs / "protocol.json", {"signature": signature, **protocol})
    protocol.update(signature=signature, fixed_at_commit=_protocol_commit(__file__))
    demos_dir = budget_demos(default_demos(args.demos if args.quick else DEMO_SEEDS[1], seed=0, scene="touch_critical"),
                             args.runs, args.demos)
    ctx = {"runs": str(args.runs), "demos_dir": str(demos_dir), "snapshots": args.snapshots,
           "batch_size": args.batch_size, "validation_seeds": args.validation_seeds, "test_seeds": args.test_seeds,
           "nominal": SETTINGS["nominal"], "settings": SETTINGS, "signature": signature}
    results: dict = {"benchmark": "touch_il_verdict_v2", "protocol": protocol}
    wall = WallTime(args.runs, args.resume)
    save = saver(results, done, args, wall, _report)

    results["force_augment_counts"] = augment_counts(Path(demos_dir), args.variants)
    _run([{"id": f"train-{v}-s{s}", "kind": "train", "variant": v, "seed": s} for s in args.seeds for v in args.variants],
         ctx, args.jobs, done, save, run_unit)
    results["steps"] = {v: choose_step([u for u in done.values() if u["kind"] == "train" and u["variant"] == v],
                                       args.snapshots) for v in args.variants}
    _run([{"id": f"test-{v}-s{s}-step{results['steps'][v]['step']}", "kind": "test", "variant": v, "seed": s,
           "step": results["steps"][v]["step"]} for s in args.seeds for v in args.variants], ctx, args.jobs, done, save, run_unit)
    save(picture=True)
    wall.finish()
    print(results["power_statement"])
    print_table(results["table"], ["variant", "setting", "mean", "ci95", "sd_over_seeds", "below_real_worst"],
                "Test success over seeds")
    print_table(results["comparisons"], ["variant", "setting", "diff", "ci95", "p_sign_flip", "p_t", "p_holm", "verdict"],
                "Against real (seed level)")
    return results


def _report(results: dict, args, picture: bool) -> None:
    """``policies`` rows, ``table`` and ``comparisons`` from the finished test units; the picture at the end."""
    from benchmarks.verdict_report import plot, summarise_seed_level

    tests = [u for u in results["units"] if u["kind"] == "test"]
    results["policies"] = [
        {"variant": u["variant"], "demos": args.demos, "train_seed": u["seed"], "setting": s, "grip_n": list(SETTINGS[s]),
         "successes": sum(o), "episodes": len(o), "checkpoint_step": u["step"], "errors": u["errors"][s], "outcomes": o}
        for u in tests for s, o in u["test"].items()]
    results["failed_units"] = [json.loads(f.read_text()) for f in sorted((args.runs / "failed").glob("*.json"))]
    results["power_statement"] = results["protocol"]["power"]["statement"]
    results["table"], results["comparisons"] = summarise_seed_level(
        tests, args.variants, args.seeds, list(SETTINGS), PRIMARY, args.demos)
    if picture and args.out is not None and results["table"]:
        plot(results["table"], args.out.with_suffix(".png"), args.variants, list(SETTINGS))


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard("python -m benchmarks.touch_il_verdict_v2", lambda: main() and 0))
