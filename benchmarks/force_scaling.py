"""Data-scaling experiment for force estimation (the paper's Table 6 and Fig. 5b) on sensor-model data.

    python -m benchmarks.force_scaling --out force_scaling.json          # full run (tens of minutes)
    python -m benchmarks.force_scaling --quick --out /tmp/fs_quick.json  # CI-sized smoke run
    python -m benchmarks.force_scaling --rows real third+copy            # rows that need no generator

"Real" means sensor-model ground truth. Every training set is made from one real training set of
P contact poses per object with K forces each; the test set is other poses (another seed), the same
for every row. Rows:

    (a) real subsets: the first k of the K forces of every pose, k in --keep (k = K is the full set)
    (b) generated alone: from the first --reference-keep real frames of every pose (a third of the
        set), the generator makes the pose's other K - k_ref forces; label = target force
    (c) that third of the real set + the generated frames of (b)  (same size as the full real set)
    (d) the full real set + the generated frames of (b)
    (copy) control: (c) with the reference frame copied instead of generated (the paper's
        reference-copy baseline), to show what the generator itself adds

Every row adds the same --no-contact frames (label 0 N) and trains the same compact CNN for the same
number of updates (--steps); only the images differ. Reported: test MAE mean ± SD over test frames
(per-frame MAE averaged over Fx, Fy, Fz), per-axis MAE, the mean |F| read on no-contact frames; all
readings are the raw network output (``predict(gate=False)``, no contact gate). The
generated frames are also read by the full-real estimator (the paper's physical check: MAE against
the target force, 0.05 N real vs 0.23 N generated in the paper).
"""

from __future__ import annotations

import hashlib
import json
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from benchmarks.common import base_parser, print_table, save_figure, write_results
from controltac_il.estimators import EstimatorConfig, ForceEstimator, EstimatorTrainConfig, fit
from controltac_il.estimators.data import estimate_noise_std, load_arrays, no_contact_residuals
from controltac_il.io import atomic_path, write_json
from controltac_il.metrics import force_mae


ROW_KINDS = ("real", "third+copy", "generated", "third+generated", "full+generated")

PROG = "python -m benchmarks.force_scaling"


@dataclass
class ScalingSetup:
    """Sizes and seeds of the experiment.

    Fields:
        poses_per_object, test_poses_per_object: contact poses per training object (train / test set).
        forces_per_pose: K, images (forces) per pose in both sets.
        keep: k values of the real subsets (a), each <= K; K itself is the full set.
        reference_keep: k of the real subset that serves as generator references in (b)-(d).
        data_seed, test_seed: seeds of the sensor-model datasets (kept apart from the generator's
            own training seed so that it never saw these poses).
        image_size: (H, W) the real frames are resized to (the generator's size).
        steps, batch_size, lr: estimator training budget, the same for every row.
        input_size: (h, w) the estimator sees.
        no_contact: no-contact frames added to every training set (label 0 N): 127 + Gaussian noise
            of ``estimate_noise_std`` of the real training frames (recorded as noise_std_grey; ≈ 2
            grey levels, noisier than the bare sensor), the same frames for every row.
        seeds: training seeds; with more than one, rows also report the SD across seeds.
        gen_steps: DDIM steps of the generator (None = its default).
    """

    poses_per_object: int = 60
    test_poses_per_object: int = 15
    forces_per_pose: int = 9
    keep: tuple[int, ...] = (1, 3, 6, 9)
    reference_keep: int = 3
    data_seed: int = 500
    test_seed: int = 1000
    image_size: tuple[int, int] = (128, 160)
    input_size: tuple[int, int] = (64, 80)
    steps: int = 1200
    batch_size: int = 64
    lr: float = 2e-3
    no_contact: int = 100
    seeds: tuple[int, ...] = (0,)
    gen_steps: int | None = None

    def __post_init__(self) -> None:
        self.keep = tuple(sorted(int(k) for k in self.keep))
        self.seeds = tuple(int(s) for s in self.seeds)
        if self.forces_per_pose < 2:
            raise ValueError(f"forces_per_pose must be >= 2, got {self.forces_per_pose}")
        if not self.keep or self.keep[0] < 1 or self.keep[-1] > self.forces_per_pose:
            raise ValueError(f"keep must list k values in [1, forces_per_pose={self.forces_per_pose}], got {self.keep}")
        if not 1 <= self.reference_keep < self.forces_per_pose:
            raise ValueError(f"reference_keep must be in [1, forces_per_pose), got {self.reference_keep}")
        if min(self.poses_per_object, self.test_poses_per_object, self.steps, self.batch_size) < 1:
            raise ValueError("poses_per_object, test_poses_per_object, steps and batch_size must be >= 1")
        if not self.seeds:
            raise ValueError("seeds must list at least one training seed")

    @classmethod
    def quick(cls) -> "ScalingSetup":
        return cls(poses_per_object=3, test_poses_per_object=2, forces_per_pose=6, keep=(2, 6),
                   reference_keep=2, steps=40, batch_size=16, no_contact=8, gen_steps=2)


# ---------------------------------------------------------------------------- plans (pure)
def subset_rows(groups: dict, k: int) -> list[int]:
    """The first ``k`` rows of every pose group, sorted (the same poses, fewer forces each)."""
    return sorted(i for key in sorted(groups) for i in groups[key][:k])


def generation_plan(groups: dict, reference_keep: int) -> tuple[np.ndarray, np.ndarray]:
    """(reference row, target row) pairs: each withheld row j >= ``reference_keep`` of a pose group
    is generated from the group's reference j mod ``reference_keep`` (references used evenly)."""
    refs, targets = [], []
    for key in sorted(groups):
        rows = groups[key]
        for j in range(reference_keep, len(rows)):
            refs.append(rows[j % reference_keep])
            targets.append(rows[j])
    return np.asarray(refs, dtype=np.int64), np.asarray(targets, dtype=np.int64)


# ---------------------------------------------------------------------------- data
def real_sets(work: Path, setup: ScalingSetup, progress: bool):
    """Write (once, cached in ``work``) and load the sensor-model train and test sets."""
    from controltac_il.tactile.dataset import load_dataset, write_dataset

    out = {}
    for name, poses, seed in (("train", setup.poses_per_object, setup.data_seed),
                              ("test", setup.test_poses_per_object, setup.test_seed)):
        path = work / f"{name}_p{poses}_k{setup.forces_per_pose}_s{seed}"
        if not (path / "manifest.csv").is_file():
            write_dataset(path, poses_per_object=poses, forces_per_pose=setup.forces_per_pose, seed=seed,
                          progress=progress)
        ds = load_dataset(path)
        x, f = load_arrays(ds, size=setup.image_size, progress=progress)
        out[name] = (ds, x, f)
    return out


def generate_frames(work: Path, x: np.ndarray, f: np.ndarray, refs: np.ndarray, targets: np.ndarray,
                    setup: ScalingSetup, generator_path, progress: bool):
    """Generated residuals for the plan and their labels (targets clamped to the generator's
    validated range, as it does), cached in ``work`` by generator hash and plan."""
    from controltac_il.generator import ForceGenerator

    gen = ForceGenerator.from_pretrained(generator_path)
    steps = gen.config.default_steps if setup.gen_steps is None else setup.gen_steps
    key = hashlib.sha256(json.dumps([gen.checkpoint_hash, steps, refs.tolist(), targets.tolist(),
                                     hashlib.sha256(x[refs].tobytes()).hexdigest()]).encode()).hexdigest()[:16]
    cache = work / f"generated_{key}.npz"
    # the generator's own range decision; a reference outside the range is kept as it is (labelled with its force)
    decision = gen.resolve_targets(f[targets], "clamp", reference_force=f[refs], reference_out_of_range="skip")
    labels = np.where(decision.skipped[:, None], f[refs], decision.target).astype(np.float32)
    clamped = int(decision.clamped.sum())
    info = {"generator_hash": gen.checkpoint_hash, "ddim_steps": int(steps), "frames": int(len(refs)),
            "targets_clamped_to_validated_range": clamped,
            "references_outside_validated_range_kept": int(decision.skipped.sum())}
    if cache.is_file():
        with np.load(cache) as z:
            info["seconds"] = float(z["seconds"])
            return z["images"], labels, info | {"cached": True}
    from tqdm.auto import tqdm
    from controltac_il.cli import tty_only

    out = np.empty((len(refs), *x.shape[1:]), np.uint8)
    chunk = 64
    t0 = time.perf_counter()
    for s in tqdm(range(0, len(refs), chunk), desc="generating", disable=tty_only(progress), unit="batch"):
        r = refs[s : s + chunk]
        out[s : s + chunk] = gen.generate_at(x[r], f[r], labels[s : s + chunk], steps=steps,
                                             seed=[int(v) for v in targets[s : s + chunk]], batch_size=chunk,
                                             reference_out_of_range="skip").residuals
    seconds = time.perf_counter() - t0
    with atomic_path(cache, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, images=out, seconds=seconds)
    return out, labels, info | {"seconds": seconds, "cached": False}


# ---------------------------------------------------------------------------- training rows
def train_row(name: str, kind: str, x: np.ndarray, f: np.ndarray, test, empty: np.ndarray, empty_test: np.ndarray,
              setup: ScalingSetup, progress: bool, cache_dir: Path | None = None) -> tuple[dict, ForceEstimator]:
    """Train on (x, f) + the no-contact frames ``empty`` with every seed; evaluate on ``test`` and
    on the held-out no-contact frames ``empty_test`` (mean |F| read, N).

    With ``cache_dir``, the row and its last estimator are stored under a key of the training
    settings and the exact data, and reused by a later run (the real rows need no generator).
    """
    xt, ft = test
    key = None
    if cache_dir is not None:
        h = hashlib.sha256()
        for a in (x, f, empty, xt, ft, empty_test):
            h.update(np.ascontiguousarray(a).tobytes())
        train_keys = ("input_size", "steps", "batch_size", "lr", "seeds")
        h.update(json.dumps([name, {k: asdict(setup)[k] for k in train_keys}]).encode())
        key = cache_dir / f"row_{h.hexdigest()[:16]}"
        if (key / "row.json").is_file():
            return json.loads((key / "row.json").read_text()), ForceEstimator.from_pretrained(key)
    cfg = EstimatorConfig(input_height=setup.input_size[0], input_width=setup.input_size[1])
    xs = np.concatenate([x, empty])
    fs = np.concatenate([f, np.zeros((len(empty), 3), np.float32)])
    per_frame, axes, zero, seed_mae, secs = [], [], [], [], []
    est = None
    for seed in setup.seeds:
        t0 = time.perf_counter()
        est, _ = fit(xs, fs, cfg, EstimatorTrainConfig(steps=setup.steps, batch_size=setup.batch_size, lr=setup.lr,
                                              seed=seed, eval_every=0, checkpoint_every=0),
                     progress=progress)
        secs.append(time.perf_counter() - t0)
        pred = est.predict(xt, gate=False)
        err = force_mae(pred, ft)
        per_frame.append(err)
        seed_mae.append(float(err.mean()))
        axes.append(np.abs(pred - ft).mean(axis=0))
        zero.append(float(np.abs(est.predict(empty_test, gate=False)).mean()))
    err = np.concatenate(per_frame)
    row = {
        "row": name, "kind": kind, "train_images": int(len(x)), "test_images": int(len(xt)),
        "mae_n": float(err.mean()), "sd_n": float(err.std()),
        "mae_fx": float(np.mean([a[0] for a in axes])), "mae_fy": float(np.mean([a[1] for a in axes])),
        "mae_fz": float(np.mean([a[2] for a in axes])),
        "seed_sd_n": float(np.std(seed_mae)) if len(seed_mae) > 1 else None,
        "no_contact_abs_n": float(np.mean(zero)), "train_seconds": float(np.median(secs)),
    }
    if key is not None:
        est.save(key)
        write_json(key / "row.json", row)
    return row, est


def plot(rows: list[dict], dest: Path, setup: ScalingSetup) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    a = [r for r in rows if r["kind"] == "real"]
    ax.errorbar([r["train_images"] for r in a], [r["mae_n"] for r in a],
                yerr=[r["sd_n"] / np.sqrt(r["test_images"]) for r in a], marker="o", label="(a) real only", color="k")
    styles = {"generated": ("s", "tab:orange", "(b) generated only"), "third+generated": ("D", "tab:green", "(c) 1/3 real + generated"),
              "full+generated": ("^", "tab:blue", "(d) all real + generated"), "third+copy": ("x", "tab:red", "control: 1/3 real + reference copies")}
    for r in rows:
        if r["kind"] in styles:
            m, c, lab = styles[r["kind"]]
            ax.errorbar([r["train_images"]], [r["mae_n"]], yerr=[r["sd_n"] / np.sqrt(r["test_images"])],
                        marker=m, color=c, linestyle="none", label=lab)
    ax.set_xlabel("training images (excluding no-contact frames)")
    ax.set_ylabel("test force MAE (N), mean over Fx, Fy, Fz\n(bars: ± SEM over test frames)", fontsize=9)
    ax.set_title(f"Force estimation vs training data (sensor model, {setup.steps} updates each)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, dest, dpi=120)


def physical_check(est, generated: tuple, real: tuple, rows: list[dict], k: int) -> dict:
    """The paper's physical check: the estimator trained on all real frames reads the generated frames
    ``(images, labels)`` and the ``real`` frames they stand in for."""
    g_err = force_mae(est.predict(generated[0], gate=False), generated[1])
    r_err = force_mae(est.predict(real[0], gate=False), real[1])
    return {"estimator": f"(a) real {k}/{k}",
            "generated_mae_n": float(g_err.mean()), "generated_sd_n": float(g_err.std()),
            "real_same_targets_mae_n": float(r_err.mean()), "real_same_targets_sd_n": float(r_err.std()),
            "real_test_mae_n": next(r["mae_n"] for r in rows if r["row"] == f"(a) real {k}/{k}"),
            "note": "generated frames of training poses vs the real frames they stand in for (training data "
                    "of this estimator, so its real error here is optimistic); test MAE is on unseen poses"}


def verdict(rows: list[dict], setup: ScalingSetup) -> dict | None:
    """A third of the real frames against all of them, and (c) against all: None without both real rows."""
    k = setup.forces_per_pose
    by_kind = {r["row"]: r for r in rows}
    full, third = by_kind.get(f"(a) real {k}/{k}"), by_kind.get(f"(a) real {setup.reference_keep}/{k}")
    if not (full and third):
        return None
    out = {"full_real_mae_n": full["mae_n"], "third_real_mae_n": third["mae_n"],
           "third_real_vs_full": third["mae_n"] / full["mae_n"]}
    c_row = next((r for r in rows if r["kind"] == "third+generated"), None)
    if c_row:
        out["third_plus_generated_vs_full"] = c_row["mae_n"] / full["mae_n"]
        out["target_c_within_10pct_of_full"] = bool(c_row["mae_n"] <= 1.10 * full["mae_n"])
    return out


def report(results: dict, n_test: int) -> None:
    """The rows' table and the summaries."""
    print_table(results["rows"], ["row", "train_images", "mae_n", "sd_n", "mae_fx", "mae_fy", "mae_fz", "seed_sd_n",
                                  "no_contact_abs_n", "train_seconds"],
                title=f"Force MAE on {n_test} test frames (unseen poses), N; {results['setup']['steps']} updates per row")
    for key in ("physical_check", "verdict", "generation"):
        if key in results:
            print(f"{key}: {json.dumps(results[key])}")


def parse(argv) -> tuple:
    """The command line and the setup it asks for (quick or full, with the flags' overrides); (args, setup)."""
    p = base_parser(PROG, __doc__.split("\n")[0])
    p.add_argument("--work-dir", type=Path, default=Path(tempfile.gettempdir()) / "controltac_force_scaling",
                   help="cache of the sensor-model datasets and generated frames (default: a folder in /tmp)")
    p.add_argument("--generator", default=None, help="generator checkpoint folder (default: the shipped one)")
    p.add_argument("--plot", type=Path, default=None, help="PNG of MAE vs training-set size (default: --out with .png)")
    p.add_argument("--steps", type=int, default=None, help="estimator updates per row (default 1200; quick 40)")
    p.add_argument("--gen-steps", type=int, default=None, help="generator DDIM steps (default: the generator's default)")
    p.add_argument("--seeds", type=int, nargs="+", default=None, help="training seeds (default 0)")
    p.add_argument("--keep", type=int, nargs="+", default=None,
                   help="k values of the real subsets (a), images kept per pose (default 1 3 6 9)")
    p.add_argument("--poses", type=int, default=None, help="training poses per object (default 60)")
    p.add_argument("--rows", nargs="+", choices=ROW_KINDS + ("generation",), default=list(ROW_KINDS), metavar="KIND",
                   help="row kinds to run (default all): real = (a), third+copy = control, generated = (b), "
                        "third+generated = (c), full+generated = (d); 'generation' only makes the generated "
                        "frames. Rows are cached in --work-dir, so separate processes can run rows in parallel "
                        "and a last full run assembles the table")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    args = p.parse_args(argv)
    setup = ScalingSetup.quick() if args.quick else ScalingSetup()
    over = {k: v for k, v in (("steps", args.steps), ("gen_steps", args.gen_steps), ("poses_per_object", args.poses),
                              ("keep", tuple(args.keep) if args.keep else None),
                              ("seeds", tuple(args.seeds) if args.seeds else None)) if v is not None}
    setup = ScalingSetup(**{**asdict(setup), **over})
    return args, setup


def main(argv=None) -> dict:
    args, setup = parse(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    progress = not args.no_progress
    work = args.work_dir / ("quick" if args.quick else "full")
    work.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    sets = real_sets(work, setup, progress)
    ds, x, f = sets["train"]
    _, xt, ft = sets["test"]
    noise_std = estimate_noise_std(x)
    empty = no_contact_residuals(setup.no_contact, *x.shape[1:3], noise_std, seed=7)
    empty_test = no_contact_residuals(50, *x.shape[1:3], noise_std, seed=8)
    groups, rows = ds.pose_groups(), []

    def add(name, kind, xs, fs):
        if kind not in args.rows:
            return None
        print(f"\n== {name}: {len(xs)} training images", flush=True)
        row, est = train_row(name, kind, xs, fs, (xt, ft), empty, empty_test, setup, progress, cache_dir=work)
        rows.append(row)
        print(f"   test MAE {row['mae_n']:.3f} ± {row['sd_n']:.3f} N", flush=True)
        return est

    K = setup.forces_per_pose
    full_est = None
    for k in setup.keep:
        idx = subset_rows(groups, k)
        est = add(f"(a) real {k}/{K}", "real", x[idx], f[idx])
        if k == K:
            full_est = est
    third = subset_rows(groups, setup.reference_keep)
    refs, targets = generation_plan(groups, setup.reference_keep)
    results: dict = {"setup": asdict(setup), "noise_std_grey": noise_std}
    add(f"control: real {setup.reference_keep}/{K} + copies", "third+copy",
        np.concatenate([x[third], x[refs]]), np.concatenate([f[third], f[targets]]))
    gen_kinds = {"generated", "third+generated", "full+generated", "generation"}
    if gen_kinds & set(args.rows):
        g, g_labels, info = generate_frames(work, x, f, refs, targets, setup, args.generator, progress)
        results["generation"] = info
        add("(b) generated only", "generated", g, g_labels)
        add(f"(c) real {setup.reference_keep}/{K} + generated", "third+generated",
            np.concatenate([x[third], g]), np.concatenate([f[third], g_labels]))
        add(f"(d) real {K}/{K} + generated", "full+generated", np.concatenate([x, g]), np.concatenate([f, g_labels]))
        if full_est is not None:
            results["physical_check"] = physical_check(full_est, (g, g_labels), (x[targets], f[targets]), rows, K)

    if (v := verdict(rows, setup)) is not None:
        results["verdict"] = v
    results["rows"] = rows
    results["total_seconds"] = time.perf_counter() - t_start
    report(results, len(xt))
    doc = write_results(args.out, results)
    if (dest := args.plot or (args.out.with_suffix(".png") if args.out else None)) is not None:
        plot(rows, dest, setup)
        print(f"wrote {dest}")
    return doc


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
