"""Calibrating to your own sensor: the estimator's and the generator's error on a sensor they never saw against
the number of presses (``python -m controltac_il.calibrate``).

    python -m benchmarks.finetune --out finetune.json [--images 0 100 500 2000] [--steps 600] [--ae-steps 600]
    python -m benchmarks.finetune --out finetune.json --resume      # keeps the budgets already done
    python -m benchmarks.finetune --plot finetune.json finetune_quality.json --out finetune.png  # both in one picture

A lab's sensor is played by one instance of the held-out family (``--instance``, default ``unseen_00``:
polynomial optics over the DIGIT background, brighter lighting than any training instance). For each budget N
its presses are rendered as a dataset folder of that one sensor (the training objects, 8 forces per pose, about
N images; what ``python -m controltac_il.tactile.dataset`` writes for a lab) and ``python -m
controltac_il.calibrate`` makes its bundle: the base estimator calibrated as calibrate chooses for that many frames
(the colour adapter, 150 steps, below 500; the whole network fine-tuned, 1000 steps, from there; ``--estimator-steps``
sets both), the base generator's autoencoder for ``--ae-steps`` steps and then its DiT, on the moved latents, for ``--steps``
steps. Both are scored on held-out poses of the same sensor: the estimator's MAE per axis (N), the generator's
MSE and SSIM against the true frame, as a ratio to copying the reference. N = 0 is the bases themselves
(zero-shot). Each budget's result is saved as it finishes; runs live under ``--runs``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np


from benchmarks.common import base_parser, machine_info, print_table, save_figure, write_results
from benchmarks.generator import dataset_pairs, quality
from controltac_il.checkpoint import read_json
from controltac_il.generator import ForceGenerator
from controltac_il.generator.checkpoint import checkpoint_hash
from controltac_il.generator.forces import VALIDATED_RANGE
from controltac_il.generator.shipped import locate_checkpoint
from controltac_il.tactile import TRAIN_OBJECTS
from controltac_il.tactile.dataset import write_dataset
from controltac_il.tactile.instances import instance_by_name

SIZE = (120, 160)
FORCES_PER_POSE = 8
EVAL_SEED = 2001  # held-out poses of the same sensor

PROG = "python -m benchmarks.finetune"


def render(root: Path, instance: str, images: int, seed: int, workers: int = 1) -> Path:
    """A one-sensor dataset folder of about ``images`` presses of the training objects (cached; the same files
    whatever ``workers``, the processes rendering it)."""
    if not (root / "manifest.csv").is_file():
        inst = instance_by_name(instance, SIZE)
        poses = max(1, round(images / (FORCES_PER_POSE * len(TRAIN_OBJECTS))))
        write_dataset(root, TRAIN_OBJECTS, poses_per_object=poses, forces_per_pose=FORCES_PER_POSE, seed=seed,
                      spec=inst.spec, optics=inst.optics, progress=False, workers=workers)
    return root


def calibrate(base: Path, data: Path, bundle: Path, args) -> Path:
    """The bundle of ``python -m controltac_il.calibrate`` on ``data`` (kept when already made, resumed when
    stopped)."""
    from controltac_il.calibrate import main as run

    if not bundle.is_dir():
        argv = ["--presses", str(data), "--out", str(bundle), "--base-generator", str(base), "--dit-steps",
                str(args.steps), "--ae-steps", str(args.ae_steps), "--lr", str(args.lr), "--device", args.device]
        if args.estimator_steps is not None:
            argv += ["--estimator-steps", str(args.estimator_steps)]
        partial = bundle.with_name(bundle.name + ".partial").is_dir()
        if run(argv + (["--resume"] if partial else [])) != 0:
            raise RuntimeError(f"calibrating on {data} failed")
    return bundle


def budget(n: int, base: Path, pairs, eval_root: Path, args) -> dict:
    """One row of the curve: ``n`` presses rendered, calibrated on, and both models scored (n = 0: the bases)."""
    t0 = time.perf_counter()
    if n == 0:
        row = {"images": 0, "images_rendered": 0, "steps": 0, "ae_steps": 0, "estimator_steps": 0,
               **score(base, pairs), **estimator_mae(None, eval_root)}
    else:
        data = render(args.runs / f"{args.instance}_n{n}", args.instance, n, 3000 + n, args.workers)
        name = f"{args.instance}_n{n}_s{args.steps}_a{args.ae_steps}_e{args.estimator_steps or 'auto'}"
        bundle = calibrate(base, data, args.runs / name, args)
        row = {"images": n, "images_rendered": int(read_json(data / "meta.json")["count"]), "steps": args.steps,
               "ae_steps": args.ae_steps, "estimator_steps": read_json(bundle / "calibration.json")["estimator"]["steps"],
               "estimator_steps_requested": args.estimator_steps, **score(bundle, pairs), **estimator_mae(bundle, eval_root)}
    return {**row, "wall_s": round(time.perf_counter() - t0, 1), "cpu": machine_info()["cpu"]}


def estimator_mae(path, eval_root: Path) -> dict:
    """MAE per axis (N) of an estimator (a checkpoint, a bundle, or None: the shipped one) on a dataset folder."""
    from controltac_il.estimators import ForceEstimator
    from controltac_il.estimators.data import load_arrays
    from controltac_il.tactile.dataset import load_dataset

    est = ForceEstimator.from_pretrained(path)
    x, f = load_arrays(load_dataset(eval_root))
    mae = np.abs(est.predict(x) - f).mean(0)
    return {"estimator_mae": [round(float(v), 4) for v in mae], "estimator_mae_fz": float(mae[2])}


def score(checkpoint, pairs) -> dict:
    refs, tgts, rf, tf, bgs = pairs
    gen = ForceGenerator.from_pretrained(checkpoint)
    pred = gen.generate(refs, tf - rf, seed=0, reference_force=gen.condition_reference(rf))
    copy, q = quality(refs, tgts, bgs, refs), quality(pred, tgts, bgs, refs)
    return {"mse": q["mse"], "mse_sd": q["mse_sd"], "ssim": q["ssim"], "copy_mse": copy["mse"],
            "copy_ssim": copy["ssim"], "mse_ratio_to_copy": q["mse"] / copy["mse"], "n": q["n"]}


def save_plot(path: Path, curves: dict[str, list[dict]], instance: str) -> None:
    """The generator's error against presses, one line per base generator (name -> its rows), and the estimator's
    MAE per axis (the first curve's: the estimator is fine-tuned alike from every base)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(9, 3.5))
    for name, rows in curves.items():
        xs = [max(r["images"], 10) for r in rows]
        ax.plot(xs, [r["mse_ratio_to_copy"] for r in rows], marker="o", label=f"base {name}")
        for x, r in zip(xs, rows):
            ax.annotate(f"{r['mse_ratio_to_copy']:.3f}", (x, r["mse_ratio_to_copy"]), textcoords="offset points",
                        xytext=(4, 4), fontsize=7)
    ax.axhline(0.35, color="grey", lw=0.8, ls="--", label="target 0.35× copy")
    ax.set(xscale="log", xlabel="presses (0 plotted at 10)", ylabel="generator MSE / reference-copy MSE",
           title=f"generator, unseen sensor {instance}")
    ax.legend(fontsize=7)
    rows = next(iter(curves.values()))
    xs = [max(r["images"], 10) for r in rows]
    for k, axis in enumerate("xyz"):
        ax2.plot(xs, [r["estimator_mae"][k] for r in rows], marker="o", label=f"F{axis}")
    ax2.set(xscale="log", yscale="log", xlabel="presses (0 plotted at 10)", ylabel="estimator MAE (N)",
            title=f"estimator, unseen sensor {instance}")
    ax2.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


def plot_runs(paths: list[Path], out: Path) -> None:
    """Draw finished runs (their ``--out`` JSONs, one instance) into one picture at ``out``."""
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise SystemExit(f"--plot: no such run file: {', '.join(missing)}")
    docs = [read_json(p) for p in paths]
    if len({d["instance"] for d in docs}) != 1:
        raise SystemExit(f"--plot: the runs were scored on different sensors ({', '.join(d['instance'] for d in docs)})")
    save_plot(out, {Path(d["base"]).name: d["rows"] for d in docs}, docs[0]["instance"])
    print(f"wrote {out}")


def _parser():
    p = base_parser(PROG, __doc__.split(":", 1)[1].strip().split("\n")[0])
    p.add_argument("--images", type=int, nargs="+", default=[0, 100, 500, 2000], help="fine-tuning budgets (images)")
    p.add_argument("--steps", type=int, default=600, help="fine-tuning steps per budget (batch 64; default 600)")
    p.add_argument("--ae-steps", type=int, default=600,
                   help="autoencoder fine-tuning steps per budget (batch 32 crops; 0 = the DiT only; default 600)")
    p.add_argument("--lr", type=float, default=2e-4, help="peak learning rate of both fine-tunes (default 2e-4)")
    p.add_argument("--estimator-steps", type=int, default=None,
                   help="estimator steps at every budget (default: calibrate's own, 150 for the colour adapter below "
                        "500 frames and 1000 for the fine-tune from there; the committed curves used 1000 at all)")
    p.add_argument("--base", default="default", help="the generator to fine-tune: default, fast, quality or a folder")
    p.add_argument("--instance", default="unseen_00", help="the held-out sensor instance playing the lab's sensor")
    p.add_argument("--pairs", type=int, default=96, help="held-out evaluation pairs (default 96)")
    p.add_argument("--runs", type=Path, default=Path("runs/finetune"), help="datasets and fine-tuned runs")
    p.add_argument("--resume", action="store_true", help="keep the budgets already in --out")
    p.add_argument("--device", default="cpu", help="where the generator fine-tunes: cpu (default) or cuda")
    p.add_argument("--workers", type=int, default=1,
                   help="processes rendering the presses (up to one per training object; default 1)")
    p.add_argument("--plot", type=Path, nargs="+", metavar="JSON",
                   help="no run: draw these finished runs (their --out files) into one picture, --out (a .png)")
    return p


def main(argv=None) -> dict | None:
    p = _parser()
    args = p.parse_args(argv)
    if args.plot:
        if args.out is None or args.out.suffix != ".png":
            p.error("--plot needs --out FILE.png")
        return plot_runs(args.plot, args.out)
    if args.quick:
        args.images, args.steps, args.ae_steps, args.pairs, args.estimator_steps = [0, 48], 4, 2, 12, 4
    if any(n < 0 for n in args.images) or args.steps < 1 or args.pairs < 1 or args.ae_steps < 0:
        p.error("--images and --ae-steps must be >= 0, --steps and --pairs >= 1")
    instance_by_name(args.instance)  # a clear error before anything renders
    base = locate_checkpoint(args.base)
    done = {}
    if args.resume and args.out is not None and args.out.is_file():
        done = {r["images"]: r for r in read_json(args.out).get("rows", []) if "estimator_mae" in r and (
            r["images"] == 0 or (r.get("steps"), r.get("ae_steps", 0), r.get("estimator_steps_requested", r.get(
                "estimator_steps"))) == (args.steps, args.ae_steps, args.estimator_steps))}
    eval_root = render(args.runs / f"{args.instance}_eval", args.instance, 288, EVAL_SEED, args.workers)
    pairs = dataset_pairs(eval_root, args.pairs)
    rows = []
    results = {"benchmark": "finetune", "instance": args.instance, "base": str(base),
               "base_hash": checkpoint_hash(base), "steps": args.steps,
               "ae_steps": args.ae_steps, "estimator_steps": args.estimator_steps, "lr": args.lr,
               "validated_range": VALIDATED_RANGE.card(), "rows": rows}
    for n in sorted(set(args.images)):
        if n in done:
            rows.append(done[n])
            continue
        rows.append(budget(n, base, pairs, eval_root, args))
        write_results(args.out, results)  # each budget saved as it finishes
    print_table(rows, ["images", "steps", "ae_steps", "mse", "copy_mse", "mse_ratio_to_copy", "ssim", "estimator_mae_fz",
                       "wall_s"],
                title=f"fine-tuning on {args.instance} (base {args.base})")
    if args.out is not None:
        save_plot(args.out.with_suffix(".png"), {args.base: rows}, args.instance)
    return write_results(args.out, results)


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
