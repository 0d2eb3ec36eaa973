"""Is the generator's force response physical? Contact area against ΔFz for a fixed reference.

    python -m benchmarks.response --out response.json [--quick] [--generator default|fast|PATH] [--plot FILE.png]

For each reference, ``generate`` is asked for ΔF = (0, 0, ΔFz) with ΔFz from -2 to +8 N in 0.5 N steps (one
noise seed) and the contact area of each output is measured: the share of the pad (%) whose residual departs
from the 127 grey offset by more than 12 grey levels (``contact_mask``). Pressing harder must not shrink the
contact: per reference the JSON gives ``max_drop_pp``, the largest fall of the area between neighbouring 0.5 N
steps (percentage points; the target is <= 0.15), and ``growth_pp``, the area at +8 N less the area at 0.

References: the real GelSight Mini frames (bead, key, seed) in ``../shared/data/real_gelsight_mini`` against
their background, at 240×320, when that folder is there (GPL: read, never copied; only the areas are written),
and the sensor model's frames of every object (the six training shapes and the six held-out ones) pressed at
the pad's centre with 3 N, three-light optics, at 120×160 (``sim120/``) and 240×320 (``sim240/``). ``--quick`` takes two objects and ΔFz in [-1, 2] N.

Detail: where a reference is larger than the model's image size, ``detail_kept`` is the energy of the output's
detail finer than the model's size (the residual less its round trip through that size) at ΔFz = +2 N over the
reference's own (``reference_fine_detail``, grey levels²): 1 = the frame's fine detail survives generation, ~0 = it
was resized away.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from benchmarks.common import REAL_GELSIGHT, base_parser, print_table, real_gelsight, save_figure, write_results
from controltac_il.tactile import HELDOUT_OBJECTS, TRAIN_OBJECTS, SensorSpec, TactileSensor, to_residual
from controltac_il.tactile.residual import contact_mask

DELTAS = np.arange(-2.0, 8.0 + 1e-9, 0.5)
QUICK_DELTAS = np.arange(-1.0, 2.0 + 1e-9, 0.5)
REFERENCE_FZ = 3.0  # N, the sensor-model references
SIM_SIZES = ((120, 160), (240, 320))  # the model's size (about) and the GelSight Mini's
MAX_DROP_PP = 0.15  # the tolerated drop between neighbouring 0.5 N steps

PROG = "python -m benchmarks.response"


def contact_area_pct(residuals: np.ndarray) -> np.ndarray:
    """Contact area (% of the pad) of each residual uint8 (B, H, W, 3) -> float (B,)."""
    return contact_mask(residuals).mean(axis=(-2, -1)) * 100.0


def fine_detail(residual: np.ndarray, size: tuple[int, int]) -> float:
    """Mean squared detail of a residual (H, W, 3) finer than ``size`` = (h, w): the residual less its area-down /
    linear-up round trip through that size (grey levels²)."""
    x = residual.astype(np.float32)
    h, w = residual.shape[:2]
    back = cv2.resize(cv2.resize(x, size[::-1], interpolation=cv2.INTER_AREA), (w, h), interpolation=cv2.INTER_LINEAR)
    return float(((x - back) ** 2).mean())


def area_drops(area: np.ndarray) -> np.ndarray:
    """The fall (pp) of the contact area between neighbouring ΔFz steps along the last axis (> 0: it shrank)."""
    return area[..., :-1] - area[..., 1:]


def response(gen, reference: np.ndarray, deltas: np.ndarray, seed: int = 0) -> dict:
    """Areas (%) of ``gen``'s outputs for one reference residual (H, W, 3) at each ΔFz, with the drop and growth,
    and (references larger than the model) the share of fine detail kept at ΔFz = +2 N."""
    d = np.zeros((len(deltas), 3))
    d[:, 2] = deltas
    out = gen.generate(np.repeat(reference[None], len(deltas), 0), d, seed=seed)
    area = contact_area_pct(out)
    model = tuple(gen.config.image_size)
    at2 = int(np.argmin(np.abs(deltas - 2.0)))
    larger = reference.shape[0] > model[0]
    ref_detail = fine_detail(reference, model) if larger else None
    detail = round(fine_detail(out[at2], model) / ref_detail, 3) if larger and deltas[at2] == 2.0 else None
    zero = int(np.argmin(np.abs(deltas)))
    drops = area_drops(area)
    worst = int(np.argmax(drops))
    max_drop = float(drops.max(initial=0.0))
    return {"reference_area_pct": round(float(contact_area_pct(reference[None])[0]), 3),
            "area_pct": [round(float(a), 3) for a in area],
            "max_drop_pp": round(max_drop, 3),
            "worst_step_n": [float(deltas[worst]), float(deltas[worst + 1])] if max_drop > 0 else None,
            "growth_pp": round(float(area[-1] - area[zero]), 3),
            "monotone": max_drop <= MAX_DROP_PP, "detail_kept": detail,
            "reference_fine_detail": None if ref_detail is None else round(ref_detail, 3)}


def real_references() -> dict[str, np.ndarray]:
    """The real frames' residuals against their background (RGB, 240×320), or {} without the shared folder."""
    try:
        bg, presses = real_gelsight()
    except FileNotFoundError:
        return {}
    return {f"real/{n}": to_residual(f, bg) for n, f in presses.items()}


def sim_references(objects, size: tuple[int, int]) -> dict[str, np.ndarray]:
    """Sensor-model residuals (``size`` pixels) of each object pressed at the pad's centre with ``REFERENCE_FZ``."""
    sensor = TactileSensor(SensorSpec.gelsight_mini().scaled(*size), optics="three_light")
    return {f"sim{size[0]}/{o}": sensor.press(o, (0.0, 0.0, 0.0), (0.0, 0.0, REFERENCE_FZ), noise_seed=0).residual
            for o in objects}


def save_plot(path: Path, deltas: np.ndarray, rows: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = ["real"] + [f"sim{h}" for h, _ in SIM_SIZES]
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4), sharex=True)
    for name, r in rows.items():
        ax = axes[panels.index(name.split("/", 1)[0])]
        area = np.asarray(r["area_pct"])
        ax.plot(deltas, area - area[int(np.argmin(np.abs(deltas)))], marker="o" if name.startswith("real/") else None,
                ms=3, lw=1.5 if name.startswith("real/") else 1.0, label=name.split("/", 1)[1])
    titles = ["real GelSight Mini frames (240×320)"] + [f"sensor model {h}×{w}, {REFERENCE_FZ:g} N references"
                                                          for h, w in SIM_SIZES]
    for ax, title in zip(axes, titles):
        ax.axhline(0, color="grey", lw=0.5)
        ax.axvline(0, color="grey", lw=0.5)
        ax.set(title=title, xlabel="ΔFz (N)", ylabel="contact area − area at ΔF = 0 (pp)")
        if ax.get_lines()[2:]:  # beyond the two axis lines: curves to name
            ax.legend(fontsize=7, ncol=2)
        else:
            ax.text(0.5, 0.5, "no frames (../shared absent)", ha="center", transform=ax.transAxes)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv=None) -> dict:
    p = base_parser(PROG, __doc__.split(":", 1)[1].strip().split("\n")[0])
    p.add_argument("--generator", default=None, help="checkpoint: default (shipped), fast, or a folder")
    p.add_argument("--plot", type=Path, default=None, help="PNG of the curves (default: beside --out)")
    args = p.parse_args(argv)
    from controltac_il.generator import ForceGenerator

    gen = ForceGenerator.from_pretrained(args.generator)
    deltas = QUICK_DELTAS if args.quick else DELTAS
    objects = (TRAIN_OBJECTS[0], HELDOUT_OBJECTS[0]) if args.quick else TRAIN_OBJECTS + HELDOUT_OBJECTS
    refs = real_references()
    for size in SIM_SIZES:
        refs.update(sim_references(objects, size))
    rows = {name: response(gen, ref, deltas) for name, ref in refs.items()}
    table = [{"reference": n, "area_at_0": r["area_pct"][int(np.argmin(np.abs(deltas)))], "max_drop_pp": r["max_drop_pp"],
              "worst_step_n": r["worst_step_n"], "growth_pp": r["growth_pp"], "monotone": r["monotone"],
              "detail_kept": r["detail_kept"]}
             for n, r in rows.items()]
    print_table(table, list(table[0]), title=f"contact area vs ΔFz ({args.generator or 'default'} generator)")
    results = {"benchmark": "response", "generator": args.generator or "default",
               "generator_hash": gen.checkpoint_hash, "delta_fz_n": deltas.tolist(), "max_drop_target_pp": MAX_DROP_PP,
               "real_frames": "read from ../shared/data/real_gelsight_mini" if REAL_GELSIGHT.is_dir() else "absent",
               "monotone": {group: f"{sum(r['monotone'] for n, r in rows.items() if n.split('/')[0] == group)} of "
                                   f"{sum(n.split('/')[0] == group for n in rows)}"
                            for group in dict.fromkeys(n.split("/")[0] for n in rows)},
               "references": rows}
    plot = args.plot or (args.out.with_suffix(".png") if args.out else None)
    if plot is not None:
        save_plot(plot, deltas, rows)
        results["plot"] = str(plot)
    return write_results(args.out, results)


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
