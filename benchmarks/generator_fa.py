"""The generator where ForceAugment uses it: the same contact at the demos' grip, pressed as ForceAugment asks.

    python -m benchmarks.generator_fa --out FILE.json [--quick] [--checkpoints fast default quality]

Pairs, per sensor (the nominal GelSight Mini; ``--instances`` randomised instances of the training family) and
size (240×320, 120×160): ``--pairs`` references, each a held-out object at a random pose (x, y U[-2, 2] mm, θ
U[-π, π]) pressed at Fz U[4, 7] N (the verdict demos' grip), and its target: ΔF as ForceAugment draws it for copy
1 or 2 of episode k (``augment.draws.plan_frame`` under the default ForceAugmentConfig: the paper's offsets
U[-3, 10] N and jitter {0, ±0.5, ±1} N), the target through the generator's own range decision
(``resolve_targets``, clamped), rendered at the same pose with another noise draw.

Per preset: MSE ÷ a reference copy's over all pairs and broken down by the sign of ΔFz, by |ΔFz| (≤ 2, 2-5, > 5 N)
and by object. Two floors: the noise floor (two renders of the target that differ only in the noise draw, ÷ the
copy's) and the contact split, the generator's and the copy's MSE on the pixels of the reference's contact area
and on the new contact (the target's contact pixels outside it: there the reference shows nothing of the object).
Beside ``--out``: the picture, each pair's MSE ÷ its copy's against ΔFz per preset with its median per 1 N, the
noise floor drawn in, and the contact split (``--plot-from JSON`` redraws it from a results JSON). Real frames (the
GelSight Mini frames of ../shared, when present): the shipped estimator's Fz read-back of outputs at each ΔFz of
``REAL_DFZ`` and the slope of read-back against ΔFz (1 N per N is ideal).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from benchmarks.common import base_parser, print_table, save_figure, write_results
from benchmarks.generator_fa_figures import DFZ_BINS, bin_label
from benchmarks.response import real_references
from benchmarks.verdict_protocols import NOMINAL, SETTINGS
from controltac_il.augment.config import ForceAugmentConfig
from controltac_il.augment.draws import plan_frame
from controltac_il.metrics import mse
from controltac_il.tactile import HELDOUT_OBJECTS, SensorSpec, TactileSensor, contact_mask, from_residual
from controltac_il.tactile.instances import sensor_instance

SIZES = {"240": (240, 320), "120": (120, 160)}
GRIP_FZ = SETTINGS[NOMINAL]  # N: the verdict demos' grip
REAL_DFZ = (-2.0, 0.0, 2.0, 4.0, 6.0)  # N
COPIES = 2  # fa2

PROG = "python -m benchmarks.generator_fa"


def fa_pairs(sensor: TactileSensor, generator, n: int, seed: int = 0,
             objects: tuple[str, ...] = HELDOUT_OBJECTS) -> dict:
    """``n`` reference/target pairs as ForceAugment asks them of ``generator`` (module docstring), of ``objects`` in
    turn: residuals uint8 (n, H, W, 3) ``ref`` and ``tgt``, ``noise`` (the target re-rendered with another noise
    draw), forces (n, 3) N ``ref_f`` and ``tgt_f`` (the used target), ``objects`` (n,), the background (H, W, 3)."""
    rng, config = np.random.default_rng(seed), ForceAugmentConfig()
    out = {k: [] for k in ("ref", "tgt", "noise", "ref_f", "tgt_f", "objects")}
    for k in range(n):
        obj = objects[k % len(objects)]
        pose = (float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)), float(rng.uniform(-np.pi, np.pi)))
        ref_f = np.array([0.0, 0.0, rng.uniform(*GRIP_FZ)])
        plan = plan_frame(config, episode=k, copy=1 + k % COPIES, frame=0, key_index=0, reference=ref_f)
        tgt_f = generator.resolve_targets(plan.target[None], "clamp", ref_f[None]).target[0]
        out["ref"].append(sensor.press(obj, pose, tuple(ref_f), noise_seed=3 * k).residual)
        out["tgt"].append(sensor.press(obj, pose, tuple(tgt_f), noise_seed=3 * k + 1).residual)
        out["noise"].append(sensor.press(obj, pose, tuple(tgt_f), noise_seed=3 * k + 2).residual)
        out["ref_f"].append(ref_f), out["tgt_f"].append(tgt_f), out["objects"].append(obj)
    return {**{k: np.stack(v) for k, v in out.items() if k != "objects"}, "objects": np.array(out["objects"]),
            "background": sensor.background}


def _mse(a: np.ndarray, b: np.ndarray, bg: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Per-pair MSE (grey levels², RGB) of images a and b (residuals + ``bg``), over ``mask`` (n, H, W) if given."""
    if mask is None:
        return mse(from_residual(a, bg), from_residual(b, bg))
    d = (from_residual(a, bg).astype(np.float64) - from_residual(b, bg)) ** 2
    m = mask[..., None]
    return (d * m).sum(axis=(1, 2, 3)) / np.maximum(m.sum(axis=(1, 2, 3)) * 3, 1)


def breakdown(pred_mse: np.ndarray, copy_mse: np.ndarray, dfz: np.ndarray, objects: np.ndarray) -> dict:
    """MSE ÷ a copy's (ratio of the means) over all pairs and per ΔFz sign, |ΔFz| bin and object; pairs per cell."""
    def cell(m):
        return {"ratio": float(pred_mse[m].mean() / copy_mse[m].mean()), "pairs": int(m.sum())} if m.any() else None

    out = {"all": cell(np.ones(len(dfz), bool)), "increase": cell(dfz > 0), "decrease": cell(dfz < 0)}
    size = np.abs(dfz)
    out.update({bin_label(lo, hi): cell(((size > lo) | (lo == 0)) & (size <= hi)) for lo, hi in DFZ_BINS})
    out["objects"] = {str(o): cell(objects == o) for o in np.unique(objects)}
    return out


def score(generator, pairs: dict) -> dict:
    """One preset on one set of pairs: the breakdown, and the contact split beside the copy's."""
    bg, ref, tgt = pairs["background"], pairs["ref"], pairs["tgt"]
    pred = generator.generate(ref, pairs["tgt_f"] - pairs["ref_f"], seed=0,
                              reference_force=generator.condition_reference(pairs["ref_f"]))
    copy_mse, pred_mse = _mse(ref, tgt, bg), _mse(pred, tgt, bg)
    dfz = pairs["tgt_f"][:, 2] - pairs["ref_f"][:, 2]
    regions = {"reference_contact": contact_mask(ref), "new_contact": contact_mask(tgt) & ~contact_mask(ref)}
    split = {f"{name}_{where}_mse": float(_mse(x, tgt, bg, m).mean()) for name, x in (("generator", pred), ("copy", ref))
             for where, m in regions.items()}
    return {**breakdown(pred_mse, copy_mse, dfz, pairs["objects"]), **split,
            "per_pair": {"dfz": dfz.tolist(), "ratio": (pred_mse / np.maximum(copy_mse, 1e-9)).tolist()}}


def floors(pairs: dict) -> dict:
    """The noise floor: MSE of two renders of each target differing only in the noise draw, ÷ the copy's MSE."""
    bg = pairs["background"]
    noise = _mse(pairs["noise"], pairs["tgt"], bg)
    return {"noise_mse": float(noise.mean()), "noise_ratio_to_copy": float(noise.mean() / _mse(pairs["ref"],
                                                                                                 pairs["tgt"], bg).mean())}


def real_readback(generator, estimator) -> dict | None:
    """On the real GelSight Mini frames: read-back Fz (N) of outputs at each ΔFz of REAL_DFZ (mean over the frames,
    minus the read-back at ΔFz = 0) and its least-squares slope against ΔFz; None without the shared frames."""
    refs = real_references()
    if not refs:
        return None
    frames = np.stack(list(refs.values()))
    rise = []
    for d in REAL_DFZ:
        out = generator.generate(frames, np.tile([[0.0, 0.0, d]], (len(frames), 1)).astype(np.float32), seed=0)
        rise.append(float(estimator.predict(out, gate=False)[:, 2].mean()))
    rise = np.array(rise) - rise[REAL_DFZ.index(0.0)]
    return {"dfz": list(REAL_DFZ), "readback_rise_n": rise.tolist(),
            "slope_n_per_n": float(np.polyfit(REAL_DFZ, rise, 1)[0]), "frames": list(refs)}


def save_plot(path, rows: list[dict]) -> None:
    """PNG: per pair, MSE ÷ its copy's against ΔFz with each preset's median per 1 N bin, one panel per size on the
    nominal sensor, the noise floor (÷ the copy's, over the pairs) dashed; beside them the contact split at 240×320:
    each preset's and the copy's MSE on the reference's contact and on the new contact."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    nominal = [r for r in rows if r["sensor"] == "nominal"]
    fig, axes = plt.subplots(1, len(nominal) + 1, figsize=(5.2 * (len(nominal) + 1), 4.6), squeeze=False)
    for ax, row in zip(axes[0], nominal):
        for k, (name, s) in enumerate(row["presets"].items()):
            dfz, ratio = np.asarray(s["per_pair"]["dfz"]), np.asarray(s["per_pair"]["ratio"])
            ax.scatter(dfz, ratio, s=8, alpha=0.35, color=f"C{k}")
            centres, medians = _binned_medians(dfz, ratio)
            ax.plot(centres, medians, color=f"C{k}", lw=2, marker="o", ms=3, label=f"{name} (line: median per 1 N)")
        ax.axhline(row["noise_ratio_to_copy"], color="black", ls="--", lw=1, label="noise floor")
        ax.axhline(1.0, color="grey", ls=":", lw=1, label="a copy")
        over_all = ", ".join(f"{n} {s['all']['ratio']:.2f}×" for n, s in row["presets"].items())
        ax.set(xlabel="ΔFz asked (N)", ylabel="MSE ÷ a copy's", yscale="log")
        ax.set_title(f"{'×'.join(map(str, SIZES[row['size']]))} frames, nominal sensor\nover all: {over_all}\n"
                     f"noise floor {row['noise_ratio_to_copy']:.2f}×", fontsize=9)
    _contact_bars(axes[0][-1], next(r for r in nominal if r["size"] == "240"))
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    save_figure(fig, path)


def _binned_medians(dfz: np.ndarray, ratio: np.ndarray, min_pairs: int = 3) -> tuple[list[float], list[float]]:
    """The median of ``ratio`` per 1 N bin of ``dfz`` (N) holding at least ``min_pairs`` pairs, at the bin's centre."""
    edges = np.arange(np.floor(dfz.min()), np.ceil(dfz.max()) + 1.0)
    centres, medians = [], []
    for lo in edges[:-1]:
        inside = (dfz >= lo) & (dfz < lo + 1.0)
        if inside.sum() >= min_pairs:
            centres.append(lo + 0.5)
            medians.append(float(np.median(ratio[inside])))
    return centres, medians


def _contact_bars(ax, row: dict) -> None:
    """Grouped bars: MSE (grey levels²) on the reference's contact and on the new contact, a copy's and each
    preset's."""
    first = next(iter(row["presets"].values()))
    bars = {"a copy": (first["copy_reference_contact_mse"], first["copy_new_contact_mse"]),
            **{n: (s["generator_reference_contact_mse"], s["generator_new_contact_mse"])
               for n, s in row["presets"].items()}}
    width = 0.8 / len(bars)
    for k, (name, values) in enumerate(bars.items()):
        ax.bar(np.arange(2) + (k - (len(bars) - 1) / 2) * width, values, width,
               color="grey" if name == "a copy" else f"C{k - 1}", label=name)
    ax.set_xticks(range(2), ["on the reference's contact", "on new contact"])
    ax.set(ylabel="MSE (grey levels²)")
    ax.set_title("where the error lies\n240×320 frames, nominal sensor", fontsize=9)
    ax.legend(fontsize=8)


def sensors(instances: int, size: tuple[int, int]) -> dict[str, TactileSensor]:
    """The nominal GelSight Mini and ``instances`` instances of the training family, at ``size``."""
    out = {"nominal": TactileSensor(SensorSpec.gelsight_mini().scaled(*size))}
    for i in range(1, instances + 1):
        inst = sensor_instance("train", i, size)
        out[inst.name] = TactileSensor(inst.spec, optics=inst.optics)
    return out


def measure(gens: dict, n: int, instances: int) -> dict:
    """The split for every generator of ``gens`` ({preset: ForceGenerator}): per size and sensor the floors and each
    preset's scores (``score``), the real frames' read-back, the settings."""
    from controltac_il.estimators import ForceEstimator

    rows, first = [], next(iter(gens.values()))
    for size, hw in SIZES.items():
        for name, sensor in sensors(instances, hw).items():
            pairs = fa_pairs(sensor, first, n)
            rows.append({"size": size, "sensor": name, "pairs": n, **floors(pairs),
                         "presets": {c: score(g, pairs) for c, g in gens.items()}})
    estimator = ForceEstimator.from_pretrained()
    return {"settings": {"pairs": n, "instances": instances, "grip_fz": list(GRIP_FZ),
                         "config": "ForceAugmentConfig() (offsets U[-3, 10] N, jitter 0/±0.5/±1 N)",
                         "checkpoints": {c: g.checkpoint_hash for c, g in gens.items()}},
            "rows": rows, "real": {c: real_readback(g, estimator) for c, g in gens.items()}}


def main(argv=None) -> dict:
    from controltac_il.generator import ForceGenerator

    p = base_parser(PROG, __doc__.splitlines()[0])
    p.add_argument("--checkpoints", nargs="+", default=["fast", "default", "quality"], help="default: the presets")
    p.add_argument("--pairs", type=int, default=None, help="pairs per sensor and size (default 96, quick 6)")
    p.add_argument("--instances", type=int, default=None, help="randomised sensor instances (default 2, quick 0)")
    p.add_argument("--plot-from", type=Path, default=None, metavar="JSON",
                   help="measure nothing: redraw the picture of a results JSON (this benchmark's, or generator.json "
                        "with its forceaugment_split) as generator_fa.png beside it")
    a = p.parse_args(argv)
    if a.plot_from is not None:
        try:
            doc = json.loads(a.plot_from.read_text())
            rows = (doc.get("forceaugment_split") or doc)["rows"]
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            p.error(f"--plot-from: {a.plot_from} is not a results JSON holding a ForceAugment split "
                    f"(this benchmark's, or generator.json's forceaugment_split): {type(exc).__name__}: {exc}")
        save_plot(a.plot_from.with_name("generator_fa.png"), rows)
        return doc
    for flag, value, low in (("--pairs", a.pairs, 1), ("--instances", a.instances, 0)):
        if value is not None and value < low:
            p.error(f"{flag}: expected an int >= {low}, got {value}")
    n = (6 if a.quick else 96) if a.pairs is None else a.pairs
    instances = (0 if a.quick else 2) if a.instances is None else a.instances
    doc = measure({c: ForceGenerator.from_pretrained(c) for c in a.checkpoints}, n, instances)
    print_table([{"size": r["size"], "sensor": r["sensor"], "preset": c, "all": s["all"]["ratio"],
                  "increase": s["increase"] and s["increase"]["ratio"], "decrease": s["decrease"] and s["decrease"]["ratio"],
                  "noise floor": r["noise_ratio_to_copy"]} for r in doc["rows"] for c, s in r["presets"].items()],
                ["size", "sensor", "preset", "all", "increase", "decrease", "noise floor"],
                title="MSE ÷ a copy's on ForceAugment's pairs (held-out objects)")
    if a.out is not None:
        save_plot(a.out.with_suffix(".png"), doc["rows"])
    return write_results(a.out, doc)


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
