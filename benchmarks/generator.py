"""Speed against error of the force-control generator, on seen poses and unseen objects.

    python -m benchmarks.generator --out gen.json [--quick] [--sheet gen.png]

Evaluation data: sensor-model datasets rendered like the training set (three-light optics, target and
reference Fz in [1, 10] N, |Fx|, |Fy| <= 1 N) with other seeds: "seen" = held-out contact poses of the six
training objects, "unseen" = the held-out objects, both at 120×160 and, as ``seen_240`` / ``unseen_240``, at the
GelSight Mini's native 240×320; "unseen_sensor" = the training objects pressed on sensor instances of the
family held out of training (``controltac_il.tactile.instances``: polynomial optics over the DIGIT background,
brighter lighting), at 120×160. Pairs are (reference, target)
images of one contact pose; the metric compares the predicted image (residual + background) with the
rendered target: MSE on 0-255 RGB and SSIM (``controltac_il.metrics``), mean ± SD over pairs, the
share of the sensor's noise kept on bare gel (``bare_noise_ratio``; 1 = as real), and the force read-back:
the shipped force estimator's Fz error (N) against the target force on the predicted frames beside that on
the true target frames (``readback_fz_mae`` / ``true_readback_fz_mae``; the estimator knows the nominal sensor
only, so on ``unseen_sensor`` both are large).

Methods: reference copy; physics re-render (``controltac_il.tactile.inverse``); "target through the model
size", a bound rather than a method: the true target resized to the generator's image size and back, i.e. what
a perfect generator working at that size would lose at 240×320 if it kept none of the frame's finer detail; the
default generator at DDIM steps 1, 2, 5, 10, 20, 50; the faster variant at 1, 2, 5; the frontier's other sizes
(``benchmarks.generator_frontier``: from-scratch tiny and small, the quality preset) at 1, 2, 5. Each generator row
records its checkpoint (``preset``) and DiT ``parameters``, and on the real GelSight Mini frames of ../shared
(``real``) its output at ΔF = 0 against the frame and the monotonicity of its contact area in Fz. For each:
images/s at batch 1 and batch 32 at 120×160, and at batch 32 at 240×320 (median of repeats, this process's torch
threads), and the peak resident memory of a fresh process generating one batch of 32 (``--quick``: the default
setting only). ``autoencoder_speed``: the autoencoder's share of a batch of 32 (one encode, two decodes) for the
shipped one and for an f8 autoencoder at 240×320, the native-resolution alternative. Beside ``--out``: the PNG
sheet. The frontier's picture joins these errors to ``benchmarks.generator_speed``'s timings
(``python -m benchmarks.generator_frontier``). ``forceaugment_split``: the presets on the pairs ForceAugment asks
for (``benchmarks.generator_fa``: held-out objects at the demos' grip, ΔF as ForceAugment draws it, broken down by
ΔFz sign, size and object, with the noise floor and the contact split; ``--fa-pairs``), its picture beside
``--out`` as ``generator_fa.png``.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import resource
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm.auto import tqdm

from benchmarks.common import base_parser, median_time, print_table, write_results
from benchmarks.generator_fa import measure as forceaugment_split, save_plot as save_fa_plot
from benchmarks.generator_frontier import FRONTIER, FRONTIER_STEPS, real_checks
from controltac_il.estimators import ForceEstimator
from controltac_il.generator import ForceGenerator
from controltac_il.generator.forces import VALIDATED_RANGE
from controltac_il.generator.shipped import CHECKPOINT_ROOT
from controltac_il.io import atomic_path, write_json
from controltac_il.metrics import mse, ssim
from controltac_il.tactile import HELDOUT_OBJECTS, TRAIN_OBJECTS, SensorSpec, TactileSensor, from_residual
from controltac_il.tactile.residual import OFFSET, residual_magnitude
from controltac_il.tactile.dataset import load_dataset, write_dataset
from controltac_il.tactile.inverse import rerender

RENDER_SIZE = (120, 160)
NATIVE_SIZE = (240, 320)
# split: objects, data seed, render size, sensor family (None: the nominal GelSight Mini)
SPLITS = {"seen": (TRAIN_OBJECTS, 1001, RENDER_SIZE, None), "unseen": (HELDOUT_OBJECTS, 1002, RENDER_SIZE, None),
          "seen_240": (TRAIN_OBJECTS, 1001, NATIVE_SIZE, None), "unseen_240": (HELDOUT_OBJECTS, 1002, NATIVE_SIZE, None),
          "unseen_sensor": (TRAIN_OBJECTS, 1003, RENDER_SIZE, "unseen")}
STEPS = (1, 2, 5, 10, 20, 50)

PROG = "python -m benchmarks.generator"


def eval_pairs(cache: Path, split: str, poses: int, forces: int, max_pairs: int, seed: int = 0):
    """(residual refs, residual targets, ref forces, target forces, backgrounds (N, H, W, 3)) of one split."""
    objects, data_seed, size, family = SPLITS[split]
    root = cache / f"{split}_p{poses}_f{forces}_s{data_seed}"
    if not (root / "manifest.csv").is_file():
        write_dataset(root, objects, poses_per_object=poses, forces_per_pose=forces, seed=data_seed,
                      spec=SensorSpec.gelsight_mini().scaled(*size), fz_range=VALIDATED_RANGE.fz, progress=False,
                      sensors=family, instances=8)
    return dataset_pairs(root, max_pairs, seed)


def dataset_pairs(root: Path, max_pairs: int, seed: int = 0):
    """``max_pairs`` seeded (reference, target) pairs of a dataset folder, each two frames of one contact pose:
    (residual refs, residual targets, ref forces, target forces, backgrounds (N, H, W, 3))."""
    ds = load_dataset(root)
    pairs = [(i, j) for g in ds.pose_groups().values() for i in g for j in g if i != j]
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(pairs), size=min(max_pairs, len(pairs)), replace=False)
    pairs = [pairs[k] for k in sorted(pick)]
    f = ds.forces()
    refs = np.stack([ds.residual(i) for i, _ in pairs])
    tgts = np.stack([ds.residual(j) for _, j in pairs])
    backgrounds = np.stack([ds.background_of(i) for i, _ in pairs])  # a pair's two frames share their sensor
    return refs, tgts, f[[i for i, _ in pairs]], f[[j for _, j in pairs]], backgrounds


def bare_noise_ratio(pred_res: np.ndarray, tgt_res: np.ndarray, ref_res: np.ndarray) -> float:
    """Sensor noise the prediction keeps on bare gel: std of the high-passed prediction over that of the
    target, on pixels without contact (< 4 grey levels) in reference and target. 1 = real noise; below
    1 the method denoises, which lowers MSE without being more like a sensor image."""
    bare = (residual_magnitude(ref_res) < 4) & (residual_magnitude(tgt_res) < 4)
    def high_pass(x):
        x = x.astype(np.float32)
        return x - np.stack([cv2.GaussianBlur(i, (0, 0), 3) for i in x])
    return float(high_pass(pred_res)[bare].std() / high_pass(tgt_res)[bare].std())


def quality(pred_res: np.ndarray, tgt_res: np.ndarray, background: np.ndarray, ref_res: np.ndarray) -> dict:
    """Mean ± SD of MSE and SSIM of predicted vs target images (residual + background (H, W, 3) or one per
    image), and the bare-gel noise ratio."""
    pred, tgt = from_residual(pred_res, background), from_residual(tgt_res, background)
    m, s = mse(pred, tgt), ssim(pred, tgt)
    return {"mse": float(m.mean()), "mse_sd": float(m.std()), "ssim": float(s.mean()), "ssim_sd": float(s.std()),
            "bare_noise_ratio": bare_noise_ratio(pred_res, tgt_res, ref_res), "n": int(len(m))}


def through_size(residual: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """A uint8 residual (H, W, 3) resized (area) to ``size`` = (h, w) and back (linear), as the generator's resize does."""
    h, w = residual.shape[:2]
    small = cv2.resize(residual, size[::-1], interpolation=cv2.INTER_AREA)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def readback(estimator: ForceEstimator, pred_res: np.ndarray, tgt_res: np.ndarray, target_force: np.ndarray) -> dict:
    """Mean |Fz| error (N) of the estimator's raw reading against the target force, on predicted and true frames."""
    def fz_mae(res):
        return float(np.abs(estimator.predict(res, gate=False)[:, 2] - target_force[:, 2]).mean())
    return {"readback_fz_mae": fz_mae(pred_res), "true_readback_fz_mae": fz_mae(tgt_res)}


def _vm_hwm_mb() -> float:
    """This process's peak resident memory (VmHWM, MB). Unlike ru_maxrss it is not inherited across exec."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _peak_worker(method: str, ckpt: str | None, steps: int | None, threads: int, q) -> None:
    torch.set_num_threads(threads)
    ref = np.full((32, *RENDER_SIZE, 3), OFFSET, np.uint8)
    df = np.tile([[0.0, 0.0, 2.0]], (32, 1))
    if method == "generator":
        gen = ForceGenerator.from_pretrained(ckpt)
        base = _vm_hwm_mb()
        gen.generate(ref, df, steps=steps, batch_size=32)
    else:
        sensor = TactileSensor(SensorSpec.gelsight_mini().scaled(*RENDER_SIZE))
        base = _vm_hwm_mb()
        for r in ref:
            rerender(sensor, r, (0, 0, 3.0), (0, 0, 5.0))
    q.put((_vm_hwm_mb(), base))


def peak_memory_mb(method: str, ckpt: str | None = None, steps: int | None = None, threads: int = 1) -> dict:
    """Peak RSS (MB) of a fresh process doing one batch of 32, and its growth over the loaded state."""
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=_peak_worker, args=(method, ckpt, steps, threads, q))
    p.start()
    peak, base = q.get(timeout=600)  # MB
    p.join()
    return {"peak_rss_mb": round(peak, 1), "batch_growth_mb": round(peak - base, 1)}


def throughput(fn_batch, refs: np.ndarray, repeats: int) -> dict:
    """Images/s at batch 1 and batch 32 (median wall time of ``repeats`` calls)."""
    one = refs[:1]
    b32 = np.concatenate([refs] * (32 // len(refs) + 1))[:32]
    t1 = median_time(lambda: fn_batch(one), repeats=repeats, warmup=1)
    t32 = median_time(lambda: fn_batch(b32), repeats=max(1, repeats // 2), warmup=1)
    return {"img_per_s_b1": 1.0 / t1, "img_per_s_b32": 32.0 / t32}


# An f8 autoencoder at the GelSight Mini's own size keeps the DiT's token count (30x40 latents, as the shipped f4 at
# 128x160 gives 32x40): the native-resolution alternative, timed untrained (its cost does not depend on training).
F8_NATIVE = {"image_size": (240, 320), "channels": (12, 24, 64), "stem_channels": 8, "latent_channels": 8}


def autoencoder_speed(shipped, repeats: int, batch: int = 32) -> dict:
    """Images/s at ``batch`` of the autoencoder's share of one ``generate`` call (one encode, two decodes) for the
    shipped autoencoder at its size and for an ``F8_NATIVE`` one at 240x320."""
    from controltac_il.generator.autoencoder import TactileAutoencoder
    from controltac_il.generator.config import AutoencoderConfig

    def speed(ae) -> float:
        x = torch.zeros(batch, 3, *ae.config.image_size)
        def once():
            with torch.no_grad():
                z = ae.encode(x)
                ae.decode(z), ae.decode(z)
        return batch / median_time(once, repeats=repeats, warmup=1)
    native = TactileAutoencoder(AutoencoderConfig(**F8_NATIVE)).eval()
    return {"batch": batch, "shipped": {"config": shipped.config.to_dict(), "img_per_s": speed(shipped)},
            "f8_at_240x320": {"config": native.config.to_dict(), "img_per_s": speed(native)}}


def error_map(pred: np.ndarray, tgt: np.ndarray) -> np.ndarray:
    """|pred - target| (max over channels) ×4, as a colour map (uint8 RGB)."""
    d = np.abs(pred.astype(np.int16) - tgt.astype(np.int16)).max(-1)
    jet = cv2.applyColorMap(np.clip(d * 4, 0, 255).astype(np.uint8), cv2.COLORMAP_JET)
    return cv2.cvtColor(jet, cv2.COLOR_BGR2RGB)


def save_sheet(path: Path, rows: list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]) -> None:
    """PNG: one row per case (split, reference, target, generated, background), columns reference | target |
    generated | error map (images, 2× size)."""
    tiles = []
    for split, ref, tgt, gen, bg in rows:
        imgs = [from_residual(ref, bg), from_residual(tgt, bg), from_residual(gen, bg), error_map(gen, tgt)]
        row = np.concatenate([cv2.resize(im, (im.shape[1] * 2, im.shape[0] * 2), interpolation=cv2.INTER_NEAREST) for im in imgs], 1)
        cv2.putText(row, split, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
        tiles.append(row)
    header = np.zeros((24, tiles[0].shape[1], 3), np.uint8)
    w = tiles[0].shape[1] // 4
    for k, name in enumerate(("reference", "target", "generated", "|error| x4")):
        cv2.putText(header, name, (k * w + 6, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1)
    sheet = np.concatenate([header, *tiles], 0)
    with atomic_path(path, suffix=".png") as tmp:
        cv2.imwrite(str(tmp), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))


def table_row(entry: dict) -> dict:
    """One printed row of the speed-vs-error table (speeds are absent for a bound; in --quick for most methods)."""
    row = {"method": entry["method"]}
    for split in SPLITS:
        q = entry[split]
        row[f"{split} MSE"] = f"{q['mse']:.1f} ± {q['mse_sd']:.1f}"
        row[f"{split} SSIM"] = f"{q['ssim']:.3f}"
    rb = entry["unseen_240"]
    return {**row, "DiT params": entry.get("parameters"), "unseen_240 Fz read-back N (true)": f"{rb['readback_fz_mae']:.2f} ({rb['true_readback_fz_mae']:.2f})",
            "unseen noise": f"{entry['unseen']['bare_noise_ratio']:.2f}", "img/s b1": entry.get("img_per_s_b1"),
            "img/s b32": entry.get("img_per_s_b32"), "img/s b32 240": entry.get("img_per_s_b32_240"),
            "peak MB": entry.get("peak_rss_mb")}


def parse(argv):
    p = base_parser(PROG, __doc__.splitlines()[0])
    p.add_argument("--checkpoint", default="default", help="default generator (shipped name or folder)")
    p.add_argument("--fast", default="fast", help="faster variant (shipped name or folder; '' to skip)")
    p.add_argument("--frontier", nargs="*", default=None, metavar="NAME",
                   help=f"the frontier's other sizes, each at DDIM {'/'.join(map(str, FRONTIER_STEPS))} (default: "
                        f"{' '.join(FRONTIER)}; --quick: none)")
    p.add_argument("--sheet", type=Path, default=None, help="PNG sheet path (default: beside --out)")
    p.add_argument("--cache", type=Path, default=Path("/tmp/controltac_generator_bench"), help="evaluation data cache")
    p.add_argument("--threads", type=int, default=torch.get_num_threads(), help="torch threads")
    p.add_argument("--pairs", type=int, default=None, help="pairs per split (default 96, quick 12)")
    p.add_argument("--fa-pairs", type=int, default=None, help="ForceAugment split: pairs per sensor and size "
                                                               "(default 96, quick 6; 0: not measured)")
    p.add_argument("--update-model-card", action="store_true", help="write the figures into the checkpoints' model_card.json")
    return p.parse_args(argv)


def methods_of(gens: dict, frontier, quick: bool) -> list[tuple[str, str, int | None]]:
    """(name, kind, DDIM steps) of every row: the copy, the two bounds, each preset at its steps."""
    methods: list[tuple[str, str, int | None]] = [("reference copy", "copy", None), ("physics re-render", "rerender", None),
                                                  ("target through the model size", "roundtrip", None)]
    methods += [(f"default DDIM-{s}", "default", s) for s in ((1, 2) if quick else STEPS)]
    if "fast" in gens:
        fs = gens["fast"].config.default_steps
        methods += [(f"fast DDIM-{s}", "fast", s) for s in sorted({1, fs, 2 * fs} | (set() if quick else set(FRONTIER_STEPS)))]
    return methods + [(f"{n} DDIM-{s}", n, s) for n in frontier for s in FRONTIER_STEPS]


def predictor(kind: str, steps: int | None, gens: dict, sensors: dict):
    """``fn(refs, ref_forces, target_forces) -> predicted frames`` of one row (not the model-size bound)."""
    if kind == "copy":
        return lambda refs, rf, tf: refs.copy()
    if kind == "rerender":
        return lambda refs, rf, tf: np.stack([rerender(sensors[refs.shape[1:3]], r, a_, b_, noise_seed=k)
                                             for k, (r, a_, b_) in enumerate(zip(refs, rf, tf))])
    g = gens[kind]
    return lambda refs, rf, tf: g.generate(refs, tf - rf, steps=steps, seed=0, batch_size=32,
                                           reference_force=g.condition_reference(rf))


def timings(entry: dict, fn, data: dict, run: dict) -> None:
    """Speed and memory of one row into ``entry`` (--quick: the default setting only). ``run``: gens, folders,
    quick, repeats, threads."""
    kind, steps, gens = entry["kind"], entry["steps"], run["gens"]

    def on(split):  # (a batch function over that split's forces, its references)
        refs, _, rf, tf, _ = data[split]
        return (lambda r: fn(r, np.resize(rf, (len(r), 3)), np.resize(tf, (len(r), 3)))), refs

    if kind in gens:
        entry["real"] = real_checks(fn)
    timed = not run["quick"] or (kind == "default" and steps == gens["default"].config.default_steps)
    if timed:
        entry.update(throughput(*on("unseen"), 1 if kind == "rerender" else run["repeats"]))
    if kind != "rerender" and timed:  # the GelSight Mini's frames, resized by the model
        entry["img_per_s_b32_240"] = throughput(*on("unseen_240"), run["repeats"])["img_per_s_b32"]
    if kind == "copy":
        entry.update(peak_rss_mb=None, batch_growth_mb=0.0)
    elif timed:
        ck = run["folders"].get(kind)
        entry.update(peak_memory_mb("generator" if ck else "rerender", ck, steps, run["threads"]))


def measure(name: str, kind: str, steps: int | None, data: dict, run: dict) -> tuple[dict, dict]:
    """One row: its error and force read-back on every split, then (a method, not the bound) its speed;
    (entry, {split: predictions})."""
    gens = run["gens"]
    fn = None if kind == "roundtrip" else predictor(kind, steps, gens, run["sensors"])
    entry = {"method": name, "kind": kind, "steps": steps, "preset": kind if kind in gens else None,
             "parameters": sum(t.numel() for t in gens[kind].denoiser.parameters()) if kind in gens else None}
    preds = {}
    for split, (refs, tgts, rf, tf, bg) in data.items():
        t0 = time.perf_counter()
        preds[split] = np.stack([through_size(t, run["model_hw"]) for t in tgts]) if fn is None else fn(refs, rf, tf)
        wall = time.perf_counter() - t0
        entry[split] = {**quality(preds[split], tgts, bg, refs), **readback(run["estimator"], preds[split], tgts, tf),
                        "wall_s": wall}
    if fn is not None:  # the bound is not a method: no speed
        timings(entry, fn, data, run)
    return entry, preds


def targets_of(per_method: dict, default_name: str) -> dict | None:
    """The default setting's figures against the benchmark's targets (None without that row)."""
    copy, dflt = per_method["reference copy"][0], per_method.get(default_name, (None,))[0]
    if dflt is None:
        return None
    return {
        "default_setting": default_name,
        "unseen_mse_ratio_to_copy": dflt["unseen"]["mse"] / copy["unseen"]["mse"],
        "unseen_mse_at_most_quarter_of_copy": dflt["unseen"]["mse"] <= 0.25 * copy["unseen"]["mse"],
        "unseen_ssim_above_copy": dflt["unseen"]["ssim"] > copy["unseen"]["ssim"],
        "unseen_240_mse_ratio_to_copy": dflt["unseen_240"]["mse"] / copy["unseen_240"]["mse"],
        "unseen_240_bound_through_model_size": (per_method["target through the model size"][0]["unseen_240"]["mse"]
                                                / copy["unseen_240"]["mse"]),
        "unseen_240_ssim_above_copy": dflt["unseen_240"]["ssim"] > copy["unseen_240"]["ssim"],
        "unseen_sensor_mse_ratio_to_copy": dflt["unseen_sensor"]["mse"] / copy["unseen_sensor"]["mse"],
        **{f"{split}_readback_ratio_to_true": dflt[split]["readback_fz_mae"] / dflt[split]["true_readback_fz_mae"]
           for split in ("seen", "unseen", "seen_240", "unseen_240")},
        "default_img_per_s_b32": dflt["img_per_s_b32"],
        "default_img_per_s_b32_240": dflt["img_per_s_b32_240"],
        "default_at_least_50_img_per_s_at_240": dflt["img_per_s_b32_240"] >= 50.0,
        "default_at_least_10_img_per_s": dflt["img_per_s_b32"] >= 10.0,
    }


def write_sheet(sheet: Path, data: dict, per_method: dict, default_name: str) -> None:
    """The default setting's largest force increases and largest decrease per 120×160 split, as a PNG sheet."""
    name = default_name if default_name in per_method else next(n for n in per_method if n.startswith("default"))
    cases = []
    for split in ("unseen", "seen", "unseen_sensor"):  # the 120×160 splits (one tile size)
        refs, tgts, rf, tf, bgs = data[split]
        order = np.argsort(-(tf[:, 2] - rf[:, 2]))  # largest force increase first
        for k in list(order[:2]) + list(order[-1:]):
            cases.append((split, refs[k], tgts[k], per_method[name][1][split][k], bgs[k]))
    save_sheet(sheet, cases)
    print(f"wrote {sheet}")


def update_cards(gens: dict, folders: dict, doc: dict, quick: bool) -> None:
    """Each measured checkpoint's model card gets the benchmark's figures for the copy, the re-render and itself."""
    for key in gens:
        ck = Path(folders[key])
        folder = CHECKPOINT_ROOT / ck if not ck.is_dir() else ck
        card_path = folder / "model_card.json"
        card = json.loads(card_path.read_text()) if card_path.is_file() else {}
        card["benchmark"] = {"command": "python -m benchmarks.generator" + (" --quick" if quick else ""),
                             "machine": doc["machine"], "settings": doc["settings"], "targets": doc["targets"],
                             "methods": [m for m in doc["methods"] if m["kind"] in ("copy", "rerender", key)]}
        write_json(card_path, card)
        print(f"updated {card_path}")


def main(argv=None) -> dict:
    a = parse(argv)
    torch.set_num_threads(a.threads)
    quick = a.quick
    n_pairs = a.pairs or (12 if quick else 96)
    repeats = 2 if quick else 5
    data = {s: eval_pairs(a.cache, s, poses=2 if quick else 8, forces=4 if quick else 6, max_pairs=n_pairs) for s in SPLITS}
    frontier = a.frontier if a.frontier is not None else (() if quick else FRONTIER)
    folders = {"default": a.checkpoint, **({"fast": a.fast} if a.fast else {}), **{n: n for n in frontier}}
    gens = {k: ForceGenerator.from_pretrained(v) for k, v in folders.items()}
    run = {"gens": gens, "folders": folders, "quick": quick, "repeats": repeats, "threads": a.threads,
           "estimator": ForceEstimator.from_pretrained(), "model_hw": tuple(gens["default"].config.image_size),
           "sensors": {size: TactileSensor(SensorSpec.gelsight_mini().scaled(*size)) for size in (RENDER_SIZE, NATIVE_SIZE)}}
    per_method = {}
    for name, kind, steps in tqdm(methods_of(gens, frontier, quick), desc="methods", unit="method", disable=None):
        per_method[name] = measure(name, kind, steps, data, run)
    rows = [table_row(entry) for entry, _ in per_method.values()]
    print_table(rows, list(rows[0]), title=f"generator speed vs error ({'quick' if quick else 'full'}, "
                                            f"{n_pairs} pairs/split, {a.threads} torch threads)")
    default_name = f"default DDIM-{gens['default'].config.default_steps}"
    targets = targets_of(per_method, default_name)
    if targets is not None:
        print("\ntargets:", json.dumps(targets, indent=1))
    if a.sheet or a.out:
        write_sheet(a.sheet or a.out.with_suffix(".png"), data, per_method, default_name)
    fa_pairs = (6 if quick else 96) if a.fa_pairs is None else a.fa_pairs
    presets = {k: gens[k] for k in ("fast", "default", "quality") if k in gens}
    split = forceaugment_split(presets, fa_pairs, 0 if quick else 2) if fa_pairs else None
    if split and a.out:
        save_fa_plot(a.out.with_name("generator_fa.png"), split["rows"])
    results = {
        "forceaugment_split": split,
        "autoencoder_speed": autoencoder_speed(gens["default"].autoencoder, repeats, 4 if quick else 32),
        "settings": {"quick": quick, "pairs_per_split": n_pairs, "render_size": list(RENDER_SIZE),
                     "splits": {k: {"objects": list(v[0]), "render_size": list(v[2]), "sensors": v[3] or "nominal"}
                                for k, v in SPLITS.items()},
                     "model_size": list(gens["default"].config.image_size), "threads": a.threads,
                     "checkpoints": {k: {"path": str(v), "hash": gens[k].checkpoint_hash} for k, v in folders.items()}},
        "methods": [entry for entry, _ in per_method.values()],
        "targets": targets,
    }
    doc = write_results(a.out, results)
    if a.update_model_card:
        update_cards(gens, folders, doc, quick)
    return doc


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
