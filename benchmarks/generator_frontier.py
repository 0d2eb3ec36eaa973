"""The generator's speed–error frontier across model sizes, for ``benchmarks.generator``: which
checkpoints it spans, their checks on real GelSight Mini frames, and its picture.

    python -m benchmarks.generator_frontier benchmarks/results/generator.json benchmarks/results/generator_speed.json

Sizes: the shipped presets ``fast`` and ``default`` (tiny DiTs with a long training lineage), and the three DiT
sizes trained under one protocol on one GPU (``benchmarks/frontier_gpu.sh``: proc240v, 8 000 steps from scratch,
each its own best step on validation): ``frontier_tiny`` (0.47 M), ``frontier_small`` (1.37 M) and the
``quality`` preset (9.9 M). Each at DDIM 1, 2 and 5.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.common import save_figure
from benchmarks.response import DELTAS, MAX_DROP_PP, area_drops, contact_area_pct, real_references
from controltac_il.cli import ArgumentParser
from controltac_il.generator.shipped import FRONTIER_SIZES
from controltac_il.metrics import mse

FRONTIER = (*FRONTIER_SIZES, "quality")  # beside fast and default, each loadable by name
FRONTIER_STEPS = (1, 2, 5)
PAPER = {"label": "ControlTac (147 M, real data)", "unseen_ratio_to_copy": 26 / 233}  # DESIGN.md's paper figures
REAL_FZ = 4.0  # the nominal reference force (N) the real frames' ΔF sweeps start from (they carry no label)

PROG = "python -m benchmarks.generator_frontier"


def real_checks(predict) -> dict | None:
    """On the real GelSight Mini frames (../shared; None where absent): the MSE (grey levels²) of the output at
    ΔF = 0 against the frame itself, and the largest contact-area drop (pp) between neighbouring 0.5 N steps of
    ΔFz in [-2, 8] N. ``predict(refs, ref_forces, target_forces)`` -> residuals."""
    refs = real_references()
    if not refs:
        return None
    frames = np.stack(list(refs.values()))
    n, rf = len(frames), np.tile([[0.0, 0.0, REAL_FZ]], (len(frames), 1))
    identity = mse(predict(frames, rf, rf), frames)
    tf = np.repeat(rf, len(DELTAS), 0)
    tf[:, 2] += np.tile(DELTAS, n)
    area = contact_area_pct(predict(np.repeat(frames, len(DELTAS), 0), np.repeat(rf, len(DELTAS), 0), tf))
    area = area.reshape(n, len(DELTAS))
    drop = float(area_drops(area).max(initial=0.0))
    return {"frames": list(refs), "identity_mse": float(identity.mean()), "identity_mse_max": float(identity.max()),
            "max_drop_pp": round(drop, 3), "monotone": drop <= MAX_DROP_PP,
            "growth_pp": round(float((area[:, -1] - area[:, list(DELTAS).index(0.0)]).min()), 3)}


def b32(row: dict) -> bool:
    """A row at batch 32 in float32, the frontier's setting (rows written before the batch and dtype columns
    existed are)."""
    return row.get("batch", 32) == 32 and row.get("dtype", "float32") == "float32"


def frontier_points(methods: list[dict], speed: list[dict]) -> dict[str, list[tuple[list[float], float, int]]]:
    """{checkpoint: [(img/s at batch 32 in float32 at 240×320 per round, unseen 240×320 MSE ÷ a copy's, DDIM steps), ...]}:
    the errors of ``benchmarks.generator``'s rows, the speeds of ``benchmarks.generator_speed``'s."""
    copy = next(m for m in methods if m["kind"] == "copy")["unseen_240"]["mse"]
    rounds = {(r["checkpoint"], r["steps"]): r["img_per_s_rounds"] for r in speed if r["frames"] == "240" and b32(r)}
    points: dict[str, list] = {}
    for m in methods:
        if m.get("parameters") and (m["kind"], m["steps"]) in rounds:
            points.setdefault(m["kind"], []).append((rounds[(m["kind"], m["steps"])], m["unseen_240"]["mse"] / copy,
                                                     m["steps"]))
    return points


def save_frontier_plot(path: Path, methods: list[dict], speed: dict) -> None:
    """PNG: error on unseen objects at 240×320 (× a reference copy's; ``methods`` of ``benchmarks.generator``)
    against images/s (median and range over rounds; ``speed``: a ``benchmarks.generator_speed`` document), one
    curve per checkpoint over its DDIM steps, with the reference copy and the paper's figure as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    params = {m["kind"]: m["parameters"] for m in methods if m.get("parameters")}
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for kind, pts in frontier_points(methods, speed["rows"]).items():
        pts = sorted(pts, key=lambda p: p[2])
        x = np.array([np.median(p[0]) for p in pts])
        spread = np.array([[xi - min(p[0]), max(p[0]) - xi] for xi, p in zip(x, pts)]).T
        ax.errorbar(x, [p[1] for p in pts], xerr=spread, marker="o", capsize=2, label=f"{kind} ({params[kind] / 1e6:.2f} M)")
        for xi, (_, y, s) in zip(x, pts):
            ax.annotate(f"{s}", (xi, y), textcoords="offset points", xytext=(4, 3), fontsize=7)
    ax.axhline(1.0, color="grey", ls=":", lw=1, label="reference copy")
    ax.axhline(PAPER["unseen_ratio_to_copy"], color="black", ls="--", lw=1,
               label=f"{PAPER['label']}: {PAPER['unseen_ratio_to_copy']:.2f}×")
    where = "CPU threads" if speed["settings"]["device"] == "cpu" else speed["machine"]["cuda_device"]
    ax.set(xscale="log", ylim=(0, 1.05), xlabel=f"images/s, batch 32 at 240×320, {speed['settings']['threads']} {where} "
                                                f"(median, range over {speed['settings']['rounds']} rounds)",
           ylabel="MSE on unseen objects at 240×320 ÷ a copy's",
           title="generator speed against error (numbers: DDIM steps)")
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    save_figure(fig, path)


def main(argv=None) -> Path:
    """Draw the frontier's picture from a ``benchmarks.generator`` JSON (errors) and a ``benchmarks.generator_speed``
    JSON (speeds), beside the first."""
    import json

    p = ArgumentParser(prog=PROG, description="Draw the generator's speed-error frontier: errors from a benchmarks.generator "
                       "JSON, speeds from a benchmarks.generator_speed JSON.")
    p.add_argument("errors", type=Path, help="the JSON benchmarks.generator wrote (the PNG goes beside it)")
    p.add_argument("speeds", type=Path, help="the JSON benchmarks.generator_speed wrote")
    a = p.parse_args(argv)
    out = a.errors.with_name(a.errors.stem + "_frontier.png")
    save_frontier_plot(out, json.loads(a.errors.read_text())["methods"], json.loads(a.speeds.read_text()))
    print(f"wrote {out}")
    return out


if __name__ == "__main__":
    from controltac_il.cli import guard

    raise SystemExit(guard(PROG, lambda: main() and 0))
