"""Levers for the pairs ForceAugment asks of the generator: chosen on validation objects, the choice tested once.

    python -m benchmarks.generator_levers --data DATA --out FILE.json [--steps 2000] [--device cpu] [--jobs 1]

``DATA`` is the shipped ``default``'s training set, rendered by its card's data command::

    python -m controltac_il.tactile.dataset --out DATA --procedural 114 --poses-per-object 30 --forces-per-pose 8 \\
        --seed 5 --size 240 320 --sensors train --instances 24 --workers 2

Each variant fine-tunes ``default``'s DiT for ``--steps`` on it with ``default``'s own recipe (its card's command:
the same flags, the same ``--val-objects 10 --seed 5``, so the same ten procedural objects are held out; peak LR
``--lr``) plus its lever (``VARIANTS``): ``control`` has none and measures what the extra steps alone give.
The shipped sizes of ``--shipped`` (``frontier_tiny``, ``frontier_small`` between ``default`` and ``quality``,
and ``quality``) are candidates too, untrained here: each held out ``default``'s validation objects.

Validation: the ForceAugment split (``benchmarks.generator_fa``'s pairs: references at the demos' grip, ΔF as
ForceAugment draws it) on those held-out procedural objects, 240×320, nominal sensor. The candidate with the lowest
MSE ÷ a copy's over all pairs is chosen, ``default`` and the shipped sizes among them. Test, once, for the chosen one and
``default``: the same split on fresh pairs of the benchmark's held-out objects, against ``TARGETS``. Runs live in
``--runs``: a finished variant is reused only if its command is this one's, a stopped one continues; nothing is
shipped from here.
"""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from benchmarks.common import base_parser, print_table, write_results
from benchmarks.generator_fa import GRIP_FZ, SIZES, fa_pairs, floors, score, sensors
from benchmarks.generator_fa_figures import TARGETS, against_targets
from controltac_il.checkpoint import read_json
from controltac_il.io import write_json
from controltac_il.generator.shipped import FRONTIER_SIZES, locate_checkpoint
from controltac_il.tactile import HELDOUT_OBJECTS

VARIANTS = {"control": [], "increase": ["--increase-prob", "0.6"], "new_contact": ["--new-contact-weight", "2"],
            "both": ["--increase-prob", "0.6", "--new-contact-weight", "2"],  # 0.6: about 80 % of pairs press harder
            "reference_force": ["--reference-force"]}
# the recipe's flags that each run sets itself (with their values)
OWN_FLAGS = ("--data", "--out", "--autoencoder-from", "--denoiser-from", "--dit-steps", "--dit-lr", "--device",
             "--threads")

PROG = "python -m benchmarks.generator_levers"


def recipe(card: dict) -> list[str]:
    """The training flags of a checkpoint's card command, without those each run sets itself."""
    words, out, k = shlex.split(card["command"]), [], 0
    words = words[words.index("--data"):] if "--data" in words else words
    while k < len(words):
        if words[k] in OWN_FLAGS:
            k += 2
            continue
        out.append(words[k])
        k += 1
    return out


def with_values(flags: list[str], values: dict[str, str]) -> list[str]:
    """``flags`` with the value after each flag of ``values`` replaced."""
    return [values[flags[k - 1]] if k and flags[k - 1] in values else w for k, w in enumerate(flags)]


def command(args, variant: str, base: list[str]) -> list[str]:
    """The training command of one variant: fine-tune ``default``'s DiT with the recipe and the variant's lever."""
    return [sys.executable, "-m", "controltac_il.generator.training", "stage1", "--data", str(args.data),
            "--out", str(args.runs / variant), "--autoencoder-from", "default", "--denoiser-from", "default",
            "--dit-steps", str(args.steps), "--dit-lr", str(args.lr), "--device", args.device,
            "--threads", str(args.threads), *base, *VARIANTS[variant]]


def train(args, variant: str, base: list[str]) -> dict:
    """Train one variant unless its run already finished with this very command; its command, training seconds
    (the card's, summed over resumes), steps, held-out objects."""
    cmd, run = command(args, variant, base), args.runs / variant
    stamp, final = run / "levers_command.json", run / "final"
    trained_here = not final.is_dir()
    if not trained_here and (not stamp.is_file() or json.loads(stamp.read_text()) != cmd[2:]):
        raise SystemExit(f"{run} holds a run of another command (see {stamp}): remove it or choose --runs")
    if trained_here:
        # a run that saved training state continues; one stopped before its first state save starts again
        state = "--resume" if (run / "denoiser_state.json").is_file() else \
            "--overwrite" if (run / "train_config.json").is_file() else None
        run.mkdir(parents=True, exist_ok=True)
        write_json(stamp, cmd[2:])
        log = args.runs / f"{variant}.log"
        with open(log, "a") as f:
            if subprocess.run(cmd + ([state] if state else []), stdout=f, stderr=subprocess.STDOUT).returncode != 0:
                raise SystemExit(f"training variant {variant} failed: see {log}")
    card = read_json(final / "model_card.json")
    return {"command": "python " + shlex.join(cmd[1:]), "trained_here": trained_here,
            "steps": card["denoiser"]["steps"], "wall_s": card["denoiser"]["wall_s"],
            "validation_objects": card["denoiser"]["validation"]["objects"],
            "symmetric_validation": card["denoiser"]["validation"].get("best")}


def split(generators: dict, objects: tuple[str, ...], n: int, seed: int) -> dict:
    """Each generator's ForceAugment split on ``n`` pairs of ``objects`` (240×320, nominal sensor), the per-pair
    lists left out, and the pairs' noise floor."""
    sensor = sensors(0, SIZES["240"])["nominal"]
    pairs = fa_pairs(sensor, next(iter(generators.values())), n, seed=seed, objects=objects)
    out = {}
    for name, g in generators.items():
        s = score(g, pairs)
        s.pop("per_pair")
        out[name] = s
    return {"floors": floors(pairs), "generators": out}


def parse(argv):
    p = base_parser(PROG, __doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="default's training set (module docstring)")
    p.add_argument("--runs", type=Path, default=None,
                   help="one run folder per variant (default runs/generator_levers, with --quick ..._quick)")
    p.add_argument("--steps", type=int, default=2000, help="DiT fine-tuning steps per variant (default 2000)")
    p.add_argument("--lr", type=float, default=1e-4, help="peak learning rate of every variant (default 1e-4)")
    p.add_argument("--val-pairs", type=int, default=256, help="ForceAugment pairs to choose on (default 256)")
    p.add_argument("--pairs", type=int, default=96, help="ForceAugment pairs of the test (default 96)")
    p.add_argument("--device", default="cpu", help="where the variants train: cpu (default) or cuda")
    p.add_argument("--threads", type=int, default=2, help="torch threads per training and for the scoring")
    p.add_argument("--jobs", type=int, default=1, help="variants trained at once")
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--shipped", nargs="*", default=[*FRONTIER_SIZES, "quality"], choices=[*FRONTIER_SIZES, "quality"],
                   help="shipped checkpoints scored as candidates beside default, untrained here (default: "
                        "frontier_tiny frontier_small quality; none with --quick)")
    args = p.parse_args(argv)
    args.runs = args.runs or Path("runs/generator_levers" + ("_quick" if args.quick else ""))
    if args.quick:  # a smoke run on a small DATA: two steps, one validation object, four pairs
        args.steps, args.pairs, args.val_pairs, args.shipped = 2, 4, 4, []
    return args


def main(argv=None) -> dict:
    import torch

    args = parse(argv)
    card = read_json(locate_checkpoint("default") / "model_card.json")
    base = recipe(card)
    if args.quick:
        base = with_values(base, {"--val-objects": "1", "--checkpoint-every": "1", "--warmup-steps": "1",
                                  "--dit-batch": "4"})
    t0 = time.perf_counter()
    with ThreadPoolExecutor(args.jobs) as pool:
        runs = dict(zip(args.variants, pool.map(lambda v: train(args, v, base), args.variants)))
    objects = validation_objects(runs, card, args.quick, args.shipped)
    torch.set_num_threads(args.threads)
    gens = candidates(args, runs)
    validation = split(gens, objects, args.val_pairs, seed=1)
    chosen = min(validation["generators"], key=lambda k: validation["generators"][k]["all"]["ratio"])
    # fresh pairs of the held-out objects (generator_fa's are seed 0), scored once, after the choice
    test = split({k: gens[k] for k in dict.fromkeys(["default", chosen])}, HELDOUT_OBJECTS, args.pairs, seed=2)
    doc = {"command": "python -m benchmarks.generator_levers " + shlex.join(sys.argv[1:] if argv is None else argv),
           "settings": {"data": str(args.data), "steps": args.steps, "lr": args.lr, "val_pairs": args.val_pairs,
                        "pairs": args.pairs, "device": args.device, "threads": args.threads, "jobs": args.jobs,
                        "quick": args.quick, "grip_fz": list(GRIP_FZ), "validation_objects": list(objects),
                        "test_seed": 2, "variants": {v: VARIANTS[v] for v in runs}, "shipped": args.shipped,
                        "checkpoints": {k: g.checkpoint_hash for k, g in gens.items()}},
           "variants": runs, "validation": validation, "chosen": chosen, "test": test,
           "targets": {k: against_targets(s) for k, s in test["generators"].items()},
           "wall_s_this_invocation": round(time.perf_counter() - t0, 1)}
    report(doc)
    return write_results(args.out, doc)


def candidates(args, runs: dict) -> dict:
    """{name: ForceGenerator} chosen among: ``default``, the shipped sizes of ``--shipped``, each trained variant."""
    from controltac_il.generator import ForceGenerator

    return {"default": ForceGenerator.from_pretrained("default"),
            **{name: ForceGenerator.from_pretrained(name) for name in args.shipped},
            **{v: ForceGenerator.from_pretrained(args.runs / v / "final") for v in runs}}


def validation_objects(runs: dict, card: dict, quick: bool, shipped: list[str]) -> tuple[str, ...]:
    """The objects every variant and every ``shipped`` candidate held out: ``default``'s own, none of the
    benchmark's held-out objects."""
    held = {tuple(r["validation_objects"]) for r in runs.values()}
    if len(held) != 1:
        raise SystemExit(f"the variants held out different validation objects: {sorted(held)}")
    objects = held.pop()
    if not quick and objects != tuple(card["denoiser"]["validation"]["objects"]):
        raise SystemExit(f"--data: the variants held out {list(objects)}, not default's validation objects "
                         f"{card['denoiser']['validation']['objects']}; render DATA with default's data command")
    if set(objects) & set(HELDOUT_OBJECTS):
        raise SystemExit(f"--data: validation objects {sorted(set(objects) & set(HELDOUT_OBJECTS))} are test objects")
    for name in shipped:
        held = read_json(locate_checkpoint(name) / "model_card.json")["denoiser"].get("validation", {}).get("objects")
        if tuple(held or ()) != objects:
            raise SystemExit(f"--shipped: {name} held out {held}, not default's validation objects {list(objects)}")
    return objects


def report(doc: dict) -> None:
    """The validation table and the test table."""
    val = doc["validation"]["generators"]
    print_table([{"candidate": k, "validation all": s["all"]["ratio"], "validation increase": s["increase"]["ratio"]}
                 for k, s in val.items()], ["candidate", "validation all", "validation increase"],
                title=f"ForceAugment split on the validation objects (chosen: {doc['chosen']})")
    print_table([{"generator": k, **t["figures"], "worst": t["worst_object"]} for k, t in doc["targets"].items()],
                ["generator", *TARGETS, "worst"], title=f"test: held-out objects (targets {TARGETS})")


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
