"""The verdict: does ForceAugment make visuo-tactile policies better? A multi-seed grid whose protocol is fixed first.

    python -m benchmarks.touch_il_verdict --out benchmarks/results/touch_il_verdict.json --jobs 2
    python -m benchmarks.touch_il_verdict --out benchmarks/results/touch_il_verdict.json --jobs 2 --resume
    python -m benchmarks.touch_il_verdict --quick --out /tmp/verdict.json          # CI size, a few seconds

PROTOCOL (committed before any augmented policy was evaluated; the JSON's ``protocol`` repeats it)

1. Seeds, three disjoint ranges [start, stop): demonstrations are scene seeds [0, 50) (scripted expert, seed 0,
   no failed attempt: ``envs.collect``); validation episodes [700000, 700030); test episodes [800000, 800050).
   Every choice below is made on validation episodes; test episodes give only the reported numbers. (Earlier
   grids evaluated at 100000 and 200000: those ranges are not reused.)
2. Recipe: ACT ``cpu`` preset (small CNN backbones, cameras 60x80, tactile 48x64, dim 128), batch 16, AdamW
   3e-4 with 50 warm-up steps then constant (so a run's snapshot at step S is the run trained to S), the demos'
   episode split seed 0 (45 train / 5 held out for the L1 curve). ``real`` and ``vision_only`` are trained for
   6000 steps with snapshots every 1000; each snapshot runs the validation episodes at nominal grip.
   Checkpoint rule: every policy is its weights at step S, with S the smallest snapshot at which ``real``
   succeeds on >= 80 % of the validation episodes for >= 4 of the 5 seeds; if no snapshot does, the snapshot
   with the highest mean ``real`` validation success (ties: fewer steps). No closed-loop selection per policy.
3. Shift: the scene's grip band is 4-7 N. Candidates, all within the finger servo's 0.5-15 N: grip 0.8-1.5,
   1.5-3, 8-10 and 11-14 N. ``real``'s snapshots at S run the validation episodes in each; its drop is the mean
   over seeds of (nominal - candidate) success. Chosen: the candidate with the largest drop below the nominal
   band and the one above it, each when its drop is >= 10 points; if neither is, the single largest, and the
   finding is that no shift costs ``real`` 10 points (ForceAugment then has little to repair here).
4. Variants at 50 demos, training seeds 0-4 for every variant (paired; the seed sets initialisation and
   sampling order; demos, split and augmentation draws are fixed): ``vision_only``, ``real``, ``fa2``, ``fa4``
   (ForceAugment with the shipped generator, the paper's offsets U[-3, 10] N and jitter {0, +-0.5, +-1} N,
   clamped to Fz 1-10 N: the clamped fraction is reported), ``image_aug`` (2 photometric copies). No other
   variant is run in this grid.
5. Each (variant, seed) policy runs the 50 test episodes at nominal grip and in each chosen shift, through
   ``controltac_il.app.evaluate_in_sim`` (the robot's control loop on the simulated robot).
6. Statistics (``benchmarks.verdict_report``): per variant and setting the mean success over seeds with a
   two-level bootstrap 95 % interval (seeds, then episodes); per comparison with ``real`` (fa2, fa4, image_aug,
   vision_only) and setting, the mean seed-paired difference with the same interval, the CMH p-value with one
   table per seed, Holm-corrected over all comparisons reported, and the seeds-as-units sign-flip p beside it.
   Verdict: "helps" / "hurts" when p_holm < 0.05 and the interval excludes 0 on that side, else "no detectable
   effect".

Every unit (one trained policy and its evaluations) is written to ``RUNS/units/`` the moment it finishes and
into ``--out``; ``--resume`` continues from either. ``--jobs 2`` runs two units side by side, one torch thread each.
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

from controltac_il.io import write_json

DEMO_SEEDS = (0, 50)
VALIDATION_SEEDS = (700_000, 700_030)
TEST_SEEDS = (800_000, 800_050)
TRAIN_SEEDS = (0, 1, 2, 3, 4)
VARIANTS = ("vision_only", "real", "fa2", "fa4", "image_aug")
TUNED = ("real", "vision_only")  # the recipe is tuned on these alone
SNAPSHOTS = (1000, 2000, 3000, 4000, 5000, 6000)
SHIFT_CANDIDATES = {"grip_0.8-1.5": (0.8, 1.5), "grip_1.5-3": (1.5, 3.0), "grip_8-10": (8.0, 10.0),
                    "grip_11-14": (11.0, 14.0)}
SERVO_RANGE_N = (0.5, 15.0)
NOMINAL = "nominal"
TARGET = {"success": 0.8, "seeds": 4}  # real at 50 demos reads touch reliably
MIN_DROP = 0.10
BATCH_SIZE = 16
DEMOS = 50
COPIES = {"fa2": 2, "fa4": 4, "image_aug": 2}


def protocol_of(args) -> dict:
    """Everything that fixes the experiment (hashed into ``signature``; a resumed grid must match it)."""
    from controltac_il.app.experiment import touch_scene

    return {"demo_seeds": list(args.demo_seeds), "validation_seeds": list(args.validation_seeds),
            "test_seeds": list(args.test_seeds), "train_seeds": list(args.seeds), "demos": args.demos,
            "variants": list(args.variants), "tuned_on": list(TUNED), "copies": {v: COPIES.get(v, 0) for v in args.variants},
            "recipe": {"preset": "cpu", "batch_size": args.batch_size, "lr": "3e-4 (preset), 50 warm-up steps, constant",
                       "split_seed": 0, "snapshots": list(args.snapshots)},
            "checkpoint_rule": (f"weights at step S: the smallest snapshot where real succeeds on >= {TARGET['success']:.0%}"
                                f" of validation episodes for >= {TARGET['seeds']} seeds, else the best mean"),
            "shift_candidates": {k: list(v) for k, v in args.shift_candidates.items()},
            "shift_rule": f"largest real drop below and above the nominal band, each if >= {MIN_DROP:.0%}; else the largest",
            "force_augment": "shipped generator, offsets U[-3, 10] N, jitter {0, +-0.5, +-1} N, clamp to Fz 1-10 N",
            "statistics": "two-level bootstrap (seeds, episodes); CMH per seed, Holm; sign-flip p over seeds",
            "scene": "PegInHoleConfig.touch_critical()", "scene_config": repr(touch_scene()),
            "nominal_grip_n": list(touch_scene().grip_force_range_n)}


def signature_of(protocol: dict) -> str:
    return hashlib.sha1(json.dumps(protocol, sort_keys=True).encode()).hexdigest()[:12]


# --- units: one trained policy and its evaluations, each saved as it finishes ------------------------------------
def _evaluate(checkpoint: Path, seeds: tuple[int, int], grip: tuple[float, float] | None) -> list[int]:
    from controltac_il.app import evaluate_in_sim

    res = evaluate_in_sim(checkpoint, episodes=seeds[1] - seeds[0], seed=seeds[0], grip_force_range=grip,
                          scene="touch_critical", progress=False)
    return [int(o["success"]) for o in res["outcomes"]]


def _train(variant: str, seed: int, steps: int, demos_dir: str, run: Path, snapshot_every: int, batch_size: int,
           max_force_copies: int) -> float:
    """Train (or finish training) one policy; returns the seconds spent now (0 when already trained)."""
    from benchmarks.touch_il import make_stage
    from controltac_il.app.experiment import train_policy

    stage = make_stage(variant, COPIES.get(variant, 0), None, max_force_copies) if variant in COPIES else None
    return train_policy(demos_dir, run, steps=steps, batch_size=batch_size, seed=seed, augment=stage,
                        vision_only=variant == "vision_only", snapshot_every=snapshot_every)


def run_unit(unit: dict, ctx: dict) -> dict:
    """Run one unit (``kind`` tune / shift / policy) and write its result to ``RUNS/units/<id>.json``."""
    import torch

    torch.set_num_threads(1)
    from controltac_il.app.experiment import snapshot_path

    runs = Path(ctx["runs"])
    v, seed, kind = unit["variant"], unit["seed"], unit["kind"]
    run = runs / "policies" / f"{v}-s{seed}"
    out = dict(unit)
    if kind == "tune":
        snaps = ctx["snapshots"]
        out["train_s"] = _train(v, seed, snaps[-1], ctx["demos_dir"], run, snaps[0], ctx["batch_size"], 0)
        out["validation"] = {str(s): _evaluate(snapshot_path(run, s), ctx["validation_seeds"], ctx["nominal"])
                             for s in snaps}
    elif kind == "shift":
        ckpt = snapshot_path(run, unit["step"])
        out["validation"] = {name: _evaluate(ckpt, ctx["validation_seeds"], tuple(band))
                             for name, band in ctx["shift_candidates"].items()}
    else:
        step = unit["step"]
        if v in TUNED:  # the tuning run's snapshot; retrained to it (same weights: constant LR) if --runs was lost
            ckpt, out["train_s"] = snapshot_path(run, step), None
            if not ckpt.is_dir():
                out["train_s"] = _train(v, seed, step, ctx["demos_dir"], run, ctx["snapshots"][0], ctx["batch_size"], 0)
        else:
            out["train_s"] = _train(v, seed, step, ctx["demos_dir"], run, 0, ctx["batch_size"], ctx["max_force_copies"])
            ckpt = run / "last"
        out["test"] = {name: _evaluate(ckpt, ctx["test_seeds"], tuple(band)) for name, band in unit["settings"].items()}
        out["grip_n"] = unit["settings"]
    out["signature"] = ctx["signature"]
    write_json(runs / "units" / f"{unit['id']}.json", out)
    return out


# --- the choices, made on validation episodes only -------------------------------------------------------------------
def choose_steps(tune: dict[tuple, dict], seeds, snapshots) -> dict:
    """The checkpoint rule (protocol point 2) applied to real's validation results."""
    import numpy as np

    curve = {}
    for s in snapshots:
        rates = [float(np.mean(tune[("real", seed)]["validation"][str(s)])) for seed in seeds]
        curve[s] = {"rates": rates, "mean": float(np.mean(rates)),
                    "seeds_at_target": sum(r >= TARGET["success"] for r in rates)}
    reached = [s for s in snapshots if curve[s]["seeds_at_target"] >= min(TARGET["seeds"], len(seeds))]
    step = reached[0] if reached else max(snapshots, key=lambda s: (curve[s]["mean"], -s))
    return {"step": step, "target_reached": bool(reached), "real_curve": {str(k): v for k, v in curve.items()}}


def choose_shifts(shift: dict[int, dict], nominal_rates: list[float], candidates: dict, nominal_band) -> dict:
    """The shift rule (protocol point 3) applied to real's validation drops at step S."""
    import numpy as np

    drops = {}
    for name in candidates:
        rates = [float(np.mean(shift[seed]["validation"][name])) for seed in sorted(shift)]
        drops[name] = {"rates": rates, "drop": float(np.mean(nominal_rates) - np.mean(rates))}
    chosen = []
    for side in ("below", "above"):
        names = [n for n in candidates if (candidates[n][1] <= nominal_band[0]) == (side == "below")]
        best = max(names, key=lambda n: drops[n]["drop"], default=None)
        if best is not None and drops[best]["drop"] >= MIN_DROP:
            chosen.append(best)
    finding = None
    if not chosen:
        chosen = [max(candidates, key=lambda n: drops[n]["drop"])]
        finding = f"no candidate shift costs real {MIN_DROP:.0%} on validation episodes"
    return {"chosen": chosen, "validation_drops": drops, "finding": finding}


# --- command line ----------------------------------------------------------------------------------------------------
def _range(p, flag: str, value) -> tuple[int, int]:
    start, stop = (int(v) for v in value)
    if not 0 <= start < stop:
        p.error(f"{flag}: [{start}, {stop}) is empty or negative")
    return start, stop


def _int_list(p, flag: str, text: str) -> list[int]:
    try:
        out = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        p.error(f"{flag}: expected a comma list of integers, got {text!r}")
    if not out or len(set(out)) != len(out) or min(out) < 0:
        p.error(f"{flag}: expected distinct integers >= 0, got {text!r}")
    return out


def _variants(p, text: str, known) -> list[str]:
    """--variants: a comma list of ``known`` names holding real (every comparison is against it)."""
    out = [v.strip() for v in text.split(",") if v.strip()]
    unknown = [v for v in out if v not in known]
    if unknown or "real" not in out:
        p.error(f"--variants: unknown {unknown} (choose from {', '.join(known)})" if unknown
                else "--variants: real is required (every comparison is against it)")
    return out


def _bands(p, text: str) -> dict:
    out = {}
    for part in [x for x in text.split(",") if x.strip()]:
        try:
            lo, hi = (float(v) for v in part.split("-"))
        except ValueError:
            p.error(f"--shift-candidates: expected LOW-HIGH grip bands in N, e.g. 1.5-3, got {part!r}")
        if not SERVO_RANGE_N[0] <= lo < hi <= SERVO_RANGE_N[1]:
            p.error(f"--shift-candidates: {part} N is empty or outside the finger servo's range "
                    f"{SERVO_RANGE_N[0]:g}-{SERVO_RANGE_N[1]:g} N")
        out[f"grip_{lo:g}-{hi:g}"] = (lo, hi)
    return out


def parse_args(argv=None):
    from benchmarks.common import base_parser

    p = base_parser(__doc__.split("\n\n")[0])
    p.add_argument("--variants", default=",".join(VARIANTS), help=f"comma list of {', '.join(VARIANTS)} (real is required)")
    p.add_argument("--seeds", default=",".join(map(str, TRAIN_SEEDS)), help="training seeds, the same for every variant (>= 5)")
    p.add_argument("--demos", type=int, default=DEMOS, help=f"demonstrations per policy (default {DEMOS}; <= --collect)")
    p.add_argument("--collect", type=int, default=DEMO_SEEDS[1], help="scripted demos collected (scene seeds from 0)")
    p.add_argument("--validation-seeds", type=int, nargs=2, default=VALIDATION_SEEDS, metavar=("START", "STOP"))
    p.add_argument("--test-seeds", type=int, nargs=2, default=TEST_SEEDS, metavar=("START", "STOP"))
    p.add_argument("--snapshots", default=",".join(map(str, SNAPSHOTS)),
                   help="steps at which real / vision_only are validated; the last is their training length")
    p.add_argument("--shift-candidates", default=",".join(f"{a:g}-{b:g}" for a, b in SHIFT_CANDIDATES.values()),
                   help="grip bands (N) from which the shift is chosen on validation episodes")
    p.add_argument("--batch-size", type=int, default=BATCH_SIZE, help=f"training batch (default {BATCH_SIZE})")
    p.add_argument("--runs", type=Path, default=Path("runs/touch_il_verdict"), help="policies and finished units")
    p.add_argument("--jobs", type=int, default=1, help="units at once (2 on 2 cores)")
    p.add_argument("--resume", action="store_true", help="continue the grid in --runs (and the rows in --out)")
    args = p.parse_args(argv)
    if args.quick:
        args.seeds, args.demos, args.collect, args.snapshots, args.batch_size = "0,1", 3, 3, "2,4", 4
        args.validation_seeds, args.test_seeds = (700_000, 700_001), (800_000, 800_002)
        if args.runs == p.get_default("runs"):
            args.runs = Path("runs/touch_il_verdict_quick")
    args.variants = _variants(p, args.variants, VARIANTS)
    args.seeds = _int_list(p, "--seeds", args.seeds)
    if len(args.seeds) < (2 if args.quick else 5):
        p.error(f"--seeds: the protocol needs >= 5 training seeds per variant, got {len(args.seeds)}")
    args.snapshots = sorted(_int_list(p, "--snapshots", args.snapshots))
    if args.snapshots[0] < 1 or any(s % args.snapshots[0] for s in args.snapshots):
        p.error(f"--snapshots: every step must be a positive multiple of the first, got {args.snapshots}")
    if not 2 <= args.demos <= args.collect:
        p.error(f"--demos: {args.demos} is not within 2..{args.collect} collected demos (--collect)")
    args.demo_seeds = (0, args.collect)
    ranges = {"demos": args.demo_seeds, "--validation-seeds": _range(p, "--validation-seeds", args.validation_seeds),
              "--test-seeds": _range(p, "--test-seeds", args.test_seeds)}
    args.validation_seeds, args.test_seeds = ranges["--validation-seeds"], ranges["--test-seeds"]
    names = list(ranges)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if ranges[a][0] < ranges[b][1] and ranges[b][0] < ranges[a][1]:
                flag = b if b.startswith("--") else a
                other = a if flag == b else b
                p.error(f"{flag}: [{ranges[flag][0]}, {ranges[flag][1]}) overlaps the {other} seeds "
                        f"[{ranges[other][0]}, {ranges[other][1]})")
    args.shift_candidates = _bands(p, args.shift_candidates)
    for name in ("jobs", "batch_size"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    return p, args


# --- the grid ----------------------------------------------------------------------------------------------------------
def _protocol_commit(module: str = __file__) -> str | None:
    """The commit that added ``module`` (a path): where its protocol was fixed (None outside a git checkout)."""
    import subprocess

    here = Path(module).resolve()
    try:
        out = subprocess.run(["git", "log", "--diff-filter=A", "--format=%h", "--", here.name], cwd=here.parent,
                             capture_output=True, text=True, check=False)
    except OSError:
        return None
    return (out.stdout.split() or [None])[-1]


def _load_done(args, p, signature: str) -> dict[str, dict]:
    """Finished units of this protocol, from ``RUNS/units`` and (with --resume) the rows already in --out."""
    guard = args.runs / "protocol.json"
    if guard.is_file():
        if not args.resume:
            p.error(f"--runs: {args.runs} already holds a grid; pass --resume to continue it or choose another --runs")
        if json.loads(guard.read_text()).get("signature") != signature:
            p.error(f"--runs: {args.runs} holds a grid of another protocol; choose another --runs folder")
    done = {}
    if args.resume and args.out is not None and args.out.is_file():
        doc = json.loads(args.out.read_text())
        if doc.get("protocol", {}).get("signature") == signature:
            done.update({u["id"]: u for u in doc.get("units", [])})
    for path in sorted((args.runs / "units").glob("*.json")):
        unit = json.loads(path.read_text())
        if unit.get("signature") == signature:
            done[unit["id"]] = unit
    return done


class WallTime:
    """A resumable grid's wall seconds across invocations: the finished ones in ``RUNS/wall_s.json``, the running
    one in ``RUNS/wall_s_running.json`` at every save (a stopped invocation counts up to its last save)."""

    def __init__(self, runs: Path, resume: bool, clock=time.perf_counter):
        self.clock = clock
        self.history_path, self.running_path = runs / "wall_s.json", runs / "wall_s_running.json"
        self.history = json.loads(self.history_path.read_text()) if resume and self.history_path.is_file() else []
        if resume and self.running_path.is_file():
            self.history.append(json.loads(self.running_path.read_text()))
            write_json(self.history_path, self.history)
            self.running_path.unlink()
        self.t0 = clock()

    def now(self) -> dict:
        """This invocation's seconds so far (also kept in the running file), the earlier ones and the total."""
        elapsed = round(self.clock() - self.t0, 1)
        write_json(self.running_path, elapsed)
        return {"this_invocation": elapsed, "earlier_invocations": self.history,
                "total": round(sum(self.history) + elapsed, 1)}

    def finish(self) -> None:
        self.history.append(round(self.clock() - self.t0, 1))
        write_json(self.history_path, self.history)
        self.running_path.unlink(missing_ok=True)


def saver(results: dict, done: dict, args, wall: WallTime, report):
    """``save(picture=False)``: the finished units into ``results``, ``report(results, args, picture)``, the wall
    time, and ``--out`` written (atomically), after every unit."""
    from benchmarks.common import write_results

    def save(picture: bool = False) -> None:
        results["units"] = sorted(done.values(), key=lambda u: u["id"])
        report(results, args, picture)
        results["wall_s"] = wall.now()
        if args.out:
            write_results(args.out, results)

    return save


def _run(units: list[dict], ctx: dict, jobs: int, done: dict, save, unit_fn=None) -> None:
    """Run the units not yet done (``unit_fn(unit, ctx)``, a module-level function; default this module's
    ``run_unit``), ``jobs`` at a time, saving after each."""
    unit_fn = unit_fn or run_unit
    from tqdm import tqdm

    todo = [u for u in units if u["id"] not in done]
    bar = tqdm(total=len(todo), desc=f"{units[0]['kind'] if units else ''} units", unit="unit", dynamic_ncols=True, disable=None)
    if jobs > 1 and len(todo) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(min(jobs, len(todo)), mp_context=multiprocessing.get_context("spawn")) as pool:
            for fut in as_completed([pool.submit(unit_fn, u, ctx) for u in todo]):
                res = fut.result()
                done[res["id"]] = res
                save()
                bar.update(1)
    else:
        for u in todo:
            done[u["id"]] = unit_fn(u, ctx)
            save()
            bar.update(1)
    bar.close()


def _clamped(demos_dir: Path, copies: dict) -> dict:
    """Build the shared ForceAugment cache once (before any worker reads it); per fa variant what its copies hold
    (``ForceAugmentStage``'s summary) and the fraction of its contact frames whose target was clamped to Fz 1-10 N."""
    from benchmarks.touch_il import make_stage
    from controltac_il.app.experiment import training_split

    train = training_split(demos_dir)
    out = {}
    for v, k in sorted(copies.items(), key=lambda x: -x[1]):  # the largest builds the cache the others read
        summary = make_stage(v, k, None, max(copies.values()))(train).summary
        contact = summary["tactile_frames"] - summary["no_contact"]
        out[v] = {**summary, "clamped_fraction_of_contact": round(summary["clamped"] / contact, 4) if contact else 0.0}
    return out


def main(argv=None) -> dict:
    p, args = parse_args(argv)
    import torch

    from benchmarks.common import print_table
    from benchmarks.touch_il import budget_demos
    from controltac_il.app import default_demos
    from controltac_il.app.experiment import touch_scene

    torch.set_num_threads(2 if args.jobs == 1 else 1)
    all_demos = default_demos(args.collect, seed=0, scene="touch_critical")
    attempts = json.loads((all_demos / "collect_info.json").read_text()).get("attempts", args.collect)
    args.demo_seeds = (0, attempts)
    for flag, (a, b) in (("--validation-seeds", args.validation_seeds), ("--test-seeds", args.test_seeds)):
        if a < attempts:
            p.error(f"{flag}: starts at {a}, inside the demos' scene seeds [0, {attempts})")
    protocol = protocol_of(args)
    signature = signature_of(protocol)
    done = _load_done(args, p, signature)
    write_json(args.runs / "protocol.json", {"signature": signature, **protocol})
    protocol.update(signature=signature, fixed_at_commit=_protocol_commit())
    demos_dir = budget_demos(all_demos, args.runs, args.demos)
    nominal = touch_scene().grip_force_range_n
    ctx = {"runs": str(args.runs), "demos_dir": str(demos_dir), "snapshots": args.snapshots, "batch_size": args.batch_size,
           "validation_seeds": args.validation_seeds, "test_seeds": args.test_seeds, "nominal": nominal,
           "shift_candidates": args.shift_candidates, "signature": signature, "max_force_copies": 0}
    results: dict = {"benchmark": "touch_il_verdict", "protocol": protocol}
    wall = WallTime(args.runs, args.resume)
    save = saver(results, done, args, wall, _report)

    _phases(args, ctx, results, done, save, Path(demos_dir))
    save(picture=True)
    wall.finish()
    print_table(results["table"], ["variant", "setting", "mean", "ci95", "per_seed"], "Test success over seeds")
    print_table(results["comparisons"], ["variant", "setting", "diff", "ci95", "p", "p_holm", "verdict"], "Against real")
    return results


def _phases(args, ctx: dict, results: dict, done: dict, save, demos_dir: Path) -> None:
    """Tune (real, vision_only on validation), choose the steps, validate real's shifts, choose them, then train
    and test every (variant, seed): the protocol's order; each phase skips the units already done."""
    tuned = [v for v in TUNED if v in args.variants]
    _run([{"id": f"tune-{v}-s{s}", "kind": "tune", "variant": v, "seed": s} for s in args.seeds for v in tuned],
         ctx, args.jobs, done, save)
    tune = {(u["variant"], u["seed"]): u for u in done.values() if u["kind"] == "tune"}
    results["steps"] = choose_steps(tune, args.seeds, args.snapshots)
    step = results["steps"]["step"]
    _run([{"id": f"shift-real-s{s}-step{step}", "kind": "shift", "variant": "real", "seed": s, "step": step}
          for s in args.seeds], ctx, args.jobs, done, save)
    shift = {u["seed"]: u for u in done.values() if u["kind"] == "shift" and u["step"] == step}
    nominal_rates = results["steps"]["real_curve"][str(step)]["rates"]
    results["shifts"] = choose_shifts(shift, nominal_rates, args.shift_candidates, ctx["nominal"])
    settings = {NOMINAL: list(ctx["nominal"]), **{n: list(args.shift_candidates[n]) for n in results["shifts"]["chosen"]}}
    fa = {v: COPIES[v] for v in args.variants if v.startswith("fa")}
    if fa:
        results["force_augment_counts"] = _clamped(demos_dir, fa)
        ctx["max_force_copies"] = max(fa.values())
    _run([{"id": f"policy-{v}-s{s}", "kind": "policy", "variant": v, "seed": s, "step": step, "settings": settings}
          for s in args.seeds for v in args.variants], ctx, args.jobs, done, save)


def _report(results: dict, args, picture: bool) -> None:
    """``policies`` rows, ``table`` and ``comparisons`` from the finished policy units; the picture at the end."""
    from benchmarks.verdict_report import plot, summarise

    units = results["units"]
    rows = []
    for u in (x for x in units if x["kind"] == "policy"):
        for setting, outcomes in u["test"].items():
            rows.append({"variant": u["variant"], "demos": args.demos, "train_seed": u["seed"], "setting": setting,
                         "grip_n": u["grip_n"][setting], "successes": sum(outcomes), "episodes": len(outcomes),
                         "train_s": u["train_s"], "checkpoint_step": u["step"], "outcomes": outcomes})
    results["policies"] = rows
    settings = list(dict.fromkeys(r["setting"] for r in rows))
    results["table"], results["comparisons"] = summarise(
        [u for u in units if u["kind"] == "policy"], args.variants, args.seeds, settings, args.demos)
    if picture and args.out is not None and results["table"]:
        plot(results["table"], args.out.with_suffix(".png"), args.variants, settings)


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard("python -m benchmarks.touch_il_verdict", lambda: main() and 0))
