"""The generator's speed–error frontier across model sizes (issue #41), for ``benchmarks.generator``: which
checkpoints it spans, their checks on real GelSight Mini frames, and its picture.

Sizes: the shipped presets ``fast`` and ``default`` (tiny DiTs with a long training lineage), and the three DiT
sizes trained under one protocol on one GPU (``benchmarks/frontier_gpu.sh``: proc240v, 8 000 steps from scratch,
each its own best step on validation): ``frontier_tiny`` (0.47 M), ``frontier_small`` (1.37 M) and the
``quality`` preset (9.9 M). Each at DDIM 1, 2 and 5.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.response import DELTAS, MAX_DROP_PP, contact_area_pct, real_references
from controltac_il.generator.shipped import CHECKPOINT_ROOT
from controltac_il.metrics import mse

FRONTIER = ("frontier_tiny", "frontier_small", "quality")
FRONTIER_STEPS = (1, 2, 5)
PAPER = {"label": "ControlTac (147 M, real data)", "unseen_ratio_to_copy": 26 / 233}  # DESIGN.md's paper figures
REAL_FZ = 4.0  # the nominal reference force (N) the real frames' ΔF sweeps start from (they carry no label)


def checkpoint_folder(name: str) -> str:
    """A shipped checkpoint's folder by name (the presets and the frontier's sizes), or ``name`` as a path."""
    folder = CHECKPOINT_ROOT / name
    return str(folder) if folder.is_dir() else name


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
    drop = float((area[:, :-1] - area[:, 1:]).max(initial=0.0))
    return {"frames": list(refs), "identity_mse": float(identity.mean()), "identity_mse_max": float(identity.max()),
            "max_drop_pp": round(drop, 3), "monotone": drop <= MAX_DROP_PP,
            "growth_pp": round(float((area[:, -1] - area[:, list(DELTAS).index(0.0)]).min()), 3)}


def frontier_points(methods: list[dict]) -> dict[str, list[tuple[float, float, int]]]:
    """{checkpoint: [(img/s at batch 32 at 240×320, unseen 240×320 MSE ÷ a copy's, DDIM steps), ...]} of the
    generator rows that were timed."""
    copy = next(m for m in methods if m["kind"] == "copy")["unseen_240"]["mse"]
    points: dict[str, list] = {}
    for m in methods:
        if m.get("parameters") and m.get("img_per_s_b32_240"):
            points.setdefault(m["kind"], []).append((m["img_per_s_b32_240"], m["unseen_240"]["mse"] / copy, m["steps"]))
    return points


def save_frontier_plot(path: Path, methods: list[dict], threads: int) -> None:
    """PNG: error on unseen objects at 240×320 (× a reference copy's) against images/s, one curve per checkpoint
    over its DDIM steps, with the reference copy and the paper's figure as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    params = {m["kind"]: m["parameters"] for m in methods if m.get("parameters")}
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for kind, pts in frontier_points(methods).items():
        pts = sorted(pts, key=lambda p: p[2])
        ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=f"{kind} ({params[kind] / 1e6:.2f} M)")
        for x, y, s in pts:
            ax.annotate(f"{s}", (x, y), textcoords="offset points", xytext=(4, 3), fontsize=7)
    ax.axhline(1.0, color="grey", ls=":", lw=1, label="reference copy")
    ax.axhline(PAPER["unseen_ratio_to_copy"], color="black", ls="--", lw=1,
               label=f"{PAPER['label']}: {PAPER['unseen_ratio_to_copy']:.2f}×")
    ax.set(xscale="log", ylim=(0, 1.05), xlabel=f"images/s, batch 32 at 240×320, {threads} CPU threads",
           ylabel="MSE on unseen objects at 240×320 ÷ a copy's",
           title="generator speed against error (numbers: DDIM steps)")
    ax.legend(fontsize=7, loc="center right")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
