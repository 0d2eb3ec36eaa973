"""The verdict: does ForceAugment make ACT better where touch matters? One runner for every protocol
(``benchmarks.verdict_protocols``), each a grid of paired training seeds on the touch-critical scene.

    python -m benchmarks.verdict --protocol v3 --out benchmarks/results/touch_il_verdict_v3.json --jobs 2
    python -m benchmarks.verdict --protocol v3 --out benchmarks/results/touch_il_verdict_v3.json --jobs 2 --resume
    python -m benchmarks.verdict --protocol v2 --out benchmarks/results/touch_il_verdict_v2.json --jobs 2
    python -m benchmarks.verdict --protocol v3 --quick --out /tmp/v3.json                 # CI size, a minute

A ``train`` unit trains one (variant, seed) to the last snapshot and validates every snapshot; a ``test`` unit
runs one policy's test episodes. Each unit is written to ``RUNS/units/`` the moment it finishes and into
``--out``, so ``--resume`` continues from either (a new session needs only the committed ``--out``). Looks are
analysed in order, each once all of its seeds' units are tested, and the grid stops where the design stops.
``--jobs 2`` runs two units side by side, one torch thread each.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from benchmarks.verdict_protocols import (DEMO_SEEDS, LOOKED_AT, NOMINAL, PROTOCOLS, USED_TRAIN_SEEDS,
                                          VALIDATION_SEEDS, Look, Protocol, record, signature_of)
from benchmarks.wall_time import WallTime
from controltac_il.io import write_json


# --- units: one (variant, seed) trained and validated, or tested; each saved as it finishes ----------------------
PROG = "python -m benchmarks.verdict"


def make_stage(variant: str):
    """The training set's augmentation of a variant (None for real)."""
    from benchmarks.touch_il import make_stage as stage
    from benchmarks.verdict_protocols import COPIES, FORCE_SETTINGS

    if variant not in COPIES:
        return None
    kind = "image_aug" if variant == "image_aug" else "fa2"
    return stage(kind, COPIES[variant], None, COPIES[variant], FORCE_SETTINGS.get(variant))


def _evaluate(checkpoint: Path, seeds, grip, where: str) -> list[int]:
    """0/1 per episode; an episode that raised stops the unit (``EvaluationError`` naming ``where``), never a 0."""
    from controltac_il.app import evaluate_in_sim

    res = evaluate_in_sim(checkpoint, episodes=seeds[1] - seeds[0], seed=seeds[0], grip_force_range=tuple(grip),
                          scene="touch_critical", progress=False, label=where)
    return [int(o["success"]) for o in res["outcomes"]]


def _test(checkpoint: Path, unit: dict, ctx: dict) -> dict[str, list[int]]:
    """The test episodes of every setting, each its own seed range."""
    return {name: _evaluate(checkpoint, ctx["test_seeds"][name], band, f"unit {unit['id']} ({name})")
            for name, band in ctx["settings"].items()}


def _train(unit: dict, ctx: dict, steps: int) -> float:
    from controltac_il.app.experiment import train_policy

    run = Path(ctx["runs"]) / "policies" / f"{unit['variant']}-s{unit['seed']}"
    return train_policy(ctx["demos_dir"], run, steps=steps, batch_size=ctx["batch_size"], seed=unit["seed"],
                        augment=make_stage(unit["variant"]), snapshot_every=ctx["snapshots"][0])


def run_unit(unit: dict, ctx: dict) -> dict:
    """Run one unit and write it to ``RUNS/units/<id>.json``. ``train``: train to the last snapshot, validate each
    (and test the last one when ``ctx["test_last"]``); ``test``: the chosen snapshot in every setting, trained
    again to it when this machine no longer holds it. A unit whose evaluation raised goes to ``RUNS/failed/``."""
    import torch

    torch.set_num_threads(1)
    from controltac_il.app import EvaluationError
    from controltac_il.app.experiment import snapshot_path

    runs, out = Path(ctx["runs"]), dict(unit)
    run = runs / "policies" / f"{unit['variant']}-s{unit['seed']}"
    try:
        if unit["kind"] == "train":
            snaps = ctx["snapshots"]
            out["train_s"] = _train(unit, ctx, snaps[-1])
            out["validation"] = {str(s): _evaluate(snapshot_path(run, s), ctx["validation_seeds"], ctx["nominal"],
                                                   f"unit {unit['id']} (validation, step {s})") for s in snaps}
            if ctx["test_last"]:
                out["test"] = _test(snapshot_path(run, snaps[-1]), unit, ctx)
        else:
            ckpt = snapshot_path(run, unit["step"])
            out["retrained_s"] = None if ckpt.is_dir() else _train(unit, ctx, unit["step"])
            out["test"] = _test(ckpt, unit, ctx)
    except EvaluationError as exc:
        write_json(runs / "failed" / f"{unit['id']}.json", {**unit, "error": str(exc), "errors": exc.result["errors"],
                                                             "signature": ctx["signature"]})
        raise
    out.update(signature=ctx["signature"], machine=ctx["machine"], augment_digest=ctx["augment_digest"])
    write_json(runs / "units" / f"{unit['id']}.json", out)
    return out


def choose_step(train_units: list[dict], snapshots) -> dict:
    """The checkpoint rule: the snapshot with the best mean validation success over ``train_units``' seeds
    (ties: fewer steps), with each snapshot's per-seed rates."""
    import numpy as np

    curve = {s: [float(np.mean(u["validation"][str(s)])) for u in sorted(train_units, key=lambda u: u["seed"])]
             for s in snapshots}
    step = max(snapshots, key=lambda s: (np.mean(curve[s]), -s))
    return {"step": step, "curve": {str(s): {"rates": r, "mean": float(np.mean(r))} for s, r in curve.items()}}


def tested(units: dict, variant: str, seed: int, step: int, last: int, test_last: bool) -> dict | None:
    """The finished unit holding (variant, seed)'s test episodes at ``step``: its test unit, or its train unit when
    the protocol tests the last snapshot in training and ``step`` is that one."""
    unit = units.get(f"train-{variant}-s{seed}" if test_last and step == last else f"test-{variant}-s{seed}-step{step}")
    return unit if unit is not None and "test" in unit else None


def augment_counts(demos_dir: Path, variants) -> dict:
    """Build each ForceAugment variant's cache (before any worker reads it); per variant its summary, clamped share
    of contact frames, histograms (1 N bins, 0-16 N) of the requested and used target Fz, and the digest of the
    cache's generated frames (units from several machines count together only when their caches hold the same
    frames)."""
    import numpy as np

    from benchmarks.verdict_protocols import FORCE_SETTINGS
    from controltac_il.app.experiment import training_split
    from controltac_il.augment.provenance import frames_digest

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
                  "requested_fz_quantiles": np.quantile(asked, [0.05, 0.5, 0.95]).round(2).tolist() if asked.size else [],
                  "cache_digest": frames_digest(Path(aug.dataset.cache_dir))}
    return out


# --- command line ------------------------------------------------------------------------------------------------
def _int_list(p, flag: str, text: str) -> list[int]:
    try:
        out = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        p.error(f"{flag}: expected a comma list of integers, got {text!r}")
    if not out or len(set(out)) != len(out) or min(out) < 0:
        p.error(f"{flag}: expected distinct integers >= 0, got {text!r}")
    return out


def quick(protocol: Protocol) -> Protocol:
    """A smoke-size version of ``protocol``: 4 seeds (looks at 2 and 4), 1 validation and 2 test episodes a setting,
    steps 2 and 4."""
    looks = tuple(dataclasses.replace(look, seeds=2 * (k + 1)) for k, look in enumerate(protocol.looks))
    return dataclasses.replace(protocol, train_seeds=protocol.train_seeds[:4], snapshots=(2, 4), looks=looks,
                               test_episodes=dict.fromkeys(protocol.test_episodes, 2), min_seeds=2,
                               validation_episodes=1)


def parse_args(argv=None):
    from benchmarks.common import base_parser

    p = base_parser(PROG, __doc__.split("\n\n")[0])
    p.add_argument("--protocol", default="v3", help="v3 (confirmatory, default) or v2 (exploratory); v1 is retired")
    p.add_argument("--seeds", default=None, help="training seeds, the same for every variant (default: the protocol's)")
    p.add_argument("--allow-underpowered", action="store_true", help="accept fewer seeds than the protocol's (tests)")
    p.add_argument("--demos", type=int, default=DEMO_SEEDS[1], help=f"demonstrations per policy (default {DEMO_SEEDS[1]})")
    p.add_argument("--test-start", type=int, default=None, help="first test episode seed (default: the protocol's)")
    p.add_argument("--batch-size", type=int, default=16, help="training batch (default 16)")
    p.add_argument("--runs", type=Path, default=None, help="policies and finished units (default runs/verdict_<protocol>)")
    p.add_argument("--jobs", type=int, default=1, help="units at once (2 on 2 cores)")
    p.add_argument("--resume", action="store_true", help="continue the grid in --runs (and the units in --out)")
    args = p.parse_args(argv)
    if args.protocol not in PROTOCOLS:
        p.error(f"--protocol: unknown {args.protocol!r} (choose from {', '.join(PROTOCOLS)})")
    proto = PROTOCOLS[args.protocol]
    if proto.retired_at:
        p.error(f"--protocol: {proto.name} is retired; its runner is at commit {proto.retired_at} "
                f"(git worktree add DIR {proto.retired_at}; python -m benchmarks.touch_il_verdict)")
    if args.quick:
        proto, args.demos, args.batch_size, args.allow_underpowered = quick(proto), 3, 4, True
    args.protocol = proto
    args.runs = args.runs or Path(f"runs/verdict_{proto.name}{'_quick' if args.quick else ''}")
    args.seeds = _int_list(p, "--seeds", args.seeds) if args.seeds else list(proto.train_seeds)
    _check_seeds(p, args, proto)
    if not 2 <= args.demos <= DEMO_SEEDS[1]:
        p.error(f"--demos: {args.demos} is not within 2..{DEMO_SEEDS[1]}")
    if args.test_start is not None:
        args.protocol = proto = dataclasses.replace(proto, test_start=args.test_start)
    _check_test_range(p, proto)
    for name in ("jobs", "batch_size"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    _check_out(p, args)
    return p, args


def _check_out(p, args) -> None:
    """--out is a new file path, or (with --resume) a grid's JSON, kept as ``args.previous`` ({} for a new file):
    refused before any unit runs."""
    args.previous = {}
    if args.out is None:
        return
    if not args.out.parent.is_dir():  # a folder as --out is refused by base_parser's results_path
        p.error(f"--out: {args.out.parent} does not exist; expected a JSON file path in an existing folder")
    if args.out.is_file() and not args.resume:
        p.error(f"--out: {args.out} exists; pass --resume to continue its grid, or choose a new file")
    if args.out.is_file():
        try:
            doc = json.loads(args.out.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            p.error(f"--out: {args.out} is not a grid's JSON ({exc})")
        if not isinstance(doc, dict) or not str(doc.get("benchmark", "")).startswith("touch_il_verdict"):
            p.error(f"--out: {args.out} is not a grid's JSON (python -m benchmarks.verdict); choose another file")
        args.previous = doc


def _check_seeds(p, args, proto: Protocol) -> None:
    """Enough seeds for the protocol (its looks' counts), none an earlier protocol trained."""
    need = proto.looks[-1].seeds if proto.looks else proto.min_seeds
    if len(args.seeds) < need and not args.allow_underpowered:
        p.error(f"--seeds: {len(args.seeds)} seeds; protocol {proto.name} needs {need}; pass --allow-underpowered "
                "for a smoke run")
    if len(args.seeds) < 2:
        p.error("--seeds: at least 2 seeds are needed for any comparison")
    if proto.looks and len(args.seeds) > proto.looks[-1].seeds:
        p.error(f"--seeds: {len(args.seeds)} seeds; protocol {proto.name}'s last look is at {proto.looks[-1].seeds}")
    for name in proto.fresh_from:
        reused = sorted(set(args.seeds) & set(USED_TRAIN_SEEDS[name]))
        if reused:
            p.error(f"--seeds: {reused} were trained by {name}; protocol {proto.name} needs fresh seeds")


def _check_test_range(p, proto: Protocol) -> None:
    """The test episodes miss the demos, the validation episodes and every range an earlier grid looked at."""
    start, stop = proto.test_start, max(proto.test_seeds(s)[1] for s in proto.test_episodes)
    taken = {"demos": DEMO_SEEDS, "validation": VALIDATION_SEEDS,
             **{k: v for k, v in LOOKED_AT.items() if not k.startswith(f"{proto.name} ")}}
    for name, (a, b) in taken.items():
        if start < b and a < stop:
            p.error(f"--test-start: test episodes [{start}, {stop}) overlap the {name} episodes [{a}, {b})")


# --- the grid ----------------------------------------------------------------------------------------------------
def _protocol_commit(path: Path) -> str | None:
    """The last commit that changed ``path`` (the protocols' module): where the protocol was fixed."""
    import subprocess

    try:
        out = subprocess.run(["git", "log", "-1", "--format=%h", "--", path.name], cwd=path.parent,
                             capture_output=True, text=True, check=False)
    except OSError:
        return None
    return out.stdout.strip() or None


def _load_done(args, p, signature: str, previous: dict) -> dict[str, dict]:
    """Finished units of this protocol, from ``RUNS/units`` and (with --resume) ``previous``, the --out already there."""
    guard = args.runs / "protocol.json"
    if guard.is_file():
        if not args.resume:
            p.error(f"--runs: {args.runs} already holds a grid; pass --resume to continue it or choose another --runs")
        if json.loads(guard.read_text()).get("signature") != signature:
            p.error(f"--runs: {args.runs} holds a grid of another protocol; choose another --runs folder")
    done = {}
    if previous:
        if previous.get("protocol", {}).get("signature") != signature:
            p.error(f"--out: {args.out} holds another protocol's grid (signature "
                    f"{previous.get('protocol', {}).get('signature')}, this one {signature})")
        done.update({u["id"]: u for u in previous.get("units", [])})
    for path in sorted((args.runs / "units").glob("*.json")):
        unit = json.loads(path.read_text())
        if unit.get("signature") == signature:
            done[unit["id"]] = unit
    return done


def _run(units: list[dict], ctx: dict, jobs: int, done: dict, save) -> None:
    """Run the units not yet done, ``jobs`` at a time, saving after each."""
    from tqdm import tqdm

    todo = [u for u in units if u["id"] not in done]
    if not todo:
        return
    bar = tqdm(total=len(todo), desc=f"{todo[0]['kind']} units", unit="unit", dynamic_ncols=True, disable=None)
    if jobs > 1 and len(todo) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(min(jobs, len(todo)), mp_context=multiprocessing.get_context("spawn")) as pool:
            for fut in as_completed([pool.submit(run_unit, u, ctx) for u in todo]):
                res = fut.result()
                done[res["id"]] = res
                save()
                bar.update(1)
    else:
        for u in todo:
            done[u["id"]] = run_unit(u, ctx)
            save()
            bar.update(1)
    bar.close()


def main(argv=None) -> dict:
    p, args = parse_args(argv)
    import torch

    from benchmarks.common import machine_info, write_results
    from benchmarks.touch_il import budget_demos
    from controltac_il.app import default_demos

    proto: Protocol = args.protocol
    torch.set_num_threads(2 if args.jobs == 1 else 1)
    generator = _check_generator(p, proto)
    protocol = record(proto, args.seeds, args.demos, args.batch_size, proto.snapshots, generator,
                      200 if args.quick else 2000)
    signature = signature_of(protocol)
    previous = args.previous
    done = _load_done(args, p, signature, previous)
    write_json(args.runs / "protocol.json", {"signature": signature, **protocol})
    protocol.update(signature=signature, fixed_at_commit=_protocol_commit(Path(__file__).with_name("verdict_protocols.py")))
    demos_dir = budget_demos(default_demos(args.demos if args.quick else DEMO_SEEDS[1], seed=0, scene="touch_critical"),
                             args.runs, args.demos)
    results: dict = {"benchmark": f"touch_il_verdict_{proto.name}", "protocol": protocol}
    earlier = previous.get("wall_s", {})
    wall = WallTime(args.runs, args.resume, earlier=[*earlier.get("earlier_invocations", []),
                                                      *([earlier["this_invocation"]] if earlier else [])])
    results["force_augment_counts"] = augment_counts(Path(demos_dir), proto.variants)
    digests = sorted({c["cache_digest"] for c in results["force_augment_counts"].values()})
    ctx = {"runs": str(args.runs), "demos_dir": str(demos_dir), "snapshots": list(proto.snapshots),
           "batch_size": args.batch_size, "validation_seeds": proto.validation_seeds, "nominal": proto.settings[NOMINAL],
           "settings": proto.settings, "test_seeds": {s: proto.test_seeds(s) for s in proto.test_episodes},
           "signature": signature, "test_last": proto.test_last_in_train, "augment_digest": ",".join(digests),
           "machine": {k: machine_info()[k] for k in ("cpu", "cores", "cuda_device")}}

    def save(picture: bool = False) -> None:
        results["units"] = sorted(done.values(), key=lambda u: u["id"])
        report(results, proto, args.seeds, args.runs, args.out, picture)
        results["wall_s"] = wall.now()
        if args.out:
            write_results(args.out, results)

    wall.start()
    _grid(proto, args, ctx, results, done, save)
    save(picture=True)
    wall.finish()
    _print(results)
    return results


def _check_generator(p, proto: Protocol) -> str:
    """The shipped default generator's hash, which must be the one the protocol pins (``figure_text``'s)."""
    from benchmarks.figure_text import SHIPPED_GENERATOR
    from controltac_il.generator.checkpoint import checkpoint_hash
    from controltac_il.generator.shipped import locate_checkpoint

    have = checkpoint_hash(locate_checkpoint(None))
    if have != SHIPPED_GENERATOR:
        p.error(f"--protocol: {proto.name} pins the default generator {SHIPPED_GENERATOR}; this checkout ships {have}")
    return have


def _grid(proto: Protocol, args, ctx: dict, results: dict, done: dict, save) -> None:
    """Look by look: train the look's new seeds, fix the steps (on look 1's seeds), test what is not tested yet,
    analyse the look; stop where the design stops."""
    seen: list[int] = []
    for k, look_seeds in enumerate(proto.look_seeds(args.seeds), start=1):
        new = [s for s in look_seeds if s not in seen]
        seen += new
        _run([{"id": f"train-{v}-s{s}", "kind": "train", "variant": v, "seed": s} for s in new for v in proto.variants],
             ctx, args.jobs, done, save)
        if k == 1:
            results["steps"] = {v: choose_step([done[f"train-{v}-s{s}"] for s in look_seeds], proto.snapshots)
                                for v in proto.variants}
        steps = {v: results["steps"][v]["step"] for v in proto.variants}
        _run([{"id": f"test-{v}-s{s}-step{steps[v]}", "kind": "test", "variant": v, "seed": s, "step": steps[v]}
              for s in new for v in proto.variants
              if not (proto.test_last_in_train and steps[v] == proto.snapshots[-1])], ctx, args.jobs, done, save)
        save()
        look = results["looks"][k - 1]
        if look.get("stop") not in (None, "continue"):
            break


def _print(results: dict) -> None:
    from benchmarks.common import print_table

    for look in results["looks"]:
        if look.get("stop"):
            print(f"look {look['look']} ({len(look['seeds'])} seeds): {look['sentence']}")
    print_table(results["table"], ["variant", "setting", "mean", "ci95", "sd_over_seeds", "below_real_worst"],
                "Test success over seeds")
    print_table(results["comparisons"], ["variant", "setting", "diff", "ci95", "p_sign_flip", "p_t", "p_holm", "verdict"],
                "Against real (seed level)")


# --- the report --------------------------------------------------------------------------------------------------
def report(results: dict, proto: Protocol, seeds, runs: Path, out: Path | None, picture: bool, reps: int = 4000) -> None:
    """``looks`` (each analysed once all its seeds are tested), and the last analysed look's ``policies``,
    ``table`` and ``comparisons``; the pictures at the end. No look's statistics exist before it is complete.
    reps: bootstrap draws per interval."""
    from benchmarks.verdict_report import plot, plot_paired

    units = {u["id"]: u for u in results["units"]}
    results["failed_units"] = [json.loads(f.read_text()) for f in sorted((runs / "failed").glob("*.json"))]
    results["power_statement"] = results["protocol"]["power"]["statement"]
    results["augment_digests"] = sorted({u["augment_digest"] for u in results["units"]})  # one: the same frames
    results["looks"], results["table"], results["comparisons"], results["policies"] = [], [], [], []
    looks = proto.looks or (Look(len(seeds), 0.05),)
    for k, (look, look_seeds) in enumerate(zip(looks, proto.look_seeds(seeds)), start=1):
        entry = analyse_look(results, proto, units, k, look, look_seeds, reps)
        results["looks"].append(entry)
        if entry["complete"] and entry["stop"] != "continue":
            break
    if picture and out is not None and results["table"]:
        plot(results["table"], out.with_suffix(".png"), list(proto.variants), list(proto.settings))
        if proto.looks:
            plot_paired(results["looks"], results["comparisons"], out.with_name(out.stem + "_paired.png"))


def analyse_look(results: dict, proto: Protocol, units: dict, k: int, look: Look, seeds: list[int],
                 reps: int = 4000) -> dict:
    """Look ``k`` over ``seeds``: {"complete": False} until every (variant, seed) is tested at its step; then its
    seed-level table and comparisons (made the report's), and for a sequential protocol the primary decision."""
    from benchmarks.verdict_report import comparison_sentence, look_decision, summarise_seed_level

    steps = {v: s["step"] for v, s in results.get("steps", {}).items()}
    last = proto.snapshots[-1]
    tests = [tested(units, v, s, steps[v], last, proto.test_last_in_train) if v in steps else None
             for s in seeds for v in proto.variants]
    entry = {"look": k, "seeds": seeds, "alpha": look.alpha, "futility": look.futility,
             "tested_units": sum(t is not None for t in tests), "units": len(tests), "complete": None not in tests}
    if not entry["complete"]:
        return entry
    holm = proto.correction == "holm"
    table, comparisons = summarise_seed_level(tests, list(proto.variants), seeds, list(proto.settings), proto.primary,
                                              results["protocol"]["demos"], reps, holm_adjust=holm)
    results["table"], results["comparisons"] = table, comparisons
    results["policies"] = [{"variant": u["variant"], "train_seed": u["seed"], "setting": s, "successes": sum(o),
                            "episodes": len(o), "checkpoint_step": steps[u["variant"]], "unit": u["id"], "outcomes": o}
                           for u in tests for s, o in u["test"].items()]
    if holm:
        entry["stop"] = "final"
        return entry
    primary = next(c for c in comparisons if (c["variant"], c["setting"]) == proto.primary[0])
    decision = look_decision(primary["per_seed_diff"], look.seeds, look.alpha, look.futility,
                             last=k == len(proto.looks))
    verdict = ("helps" if primary["diff"] > 0 else "hurts") if decision["reject"] else "no detectable effect"
    primary["verdict"] = verdict if decision["stop"] != "continue" else None
    primary["sentence"] = comparison_sentence(primary)
    entry.update(decision, verdict=primary["verdict"], diff=primary["diff"], ci95=primary["ci95"],
                 sentence=f"{decision['stop']}: {verdict if decision['stop'] != 'continue' else 'continue to the next look'}"
                          f" ({primary['variant']} - real at {primary['setting']}: {primary['diff'] * 100:+.1f} points,"
                          f" 95 % CI {primary['ci95'][0] * 100:+.1f} to {primary['ci95'][1] * 100:+.1f}, sign-flip p "
                          f"{decision['p']:.3g} against alpha {look.alpha:g})")
    return entry


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
