"""What a calibration fitted and how well: the table (stdout and the bundle's README) and ``report.png``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

REPORT_DFZ = (-3.0, 2.0, 5.0)  # N: the ΔFz of the report's generated frames (clamped into the validated range)


def table(record: dict) -> str:
    """One table (markdown) of the held-out figures: estimator MAE against the constant, generator against a copy."""
    e, g = record["estimator"], record["generator"]
    h = e["held_out"]
    rows = ["| on held-out grasps | calibrated | before (base) | baseline |", "| --- | --- | --- | --- |",
            f"| estimator Fz MAE, N ({h['frames']} frames, {h['grasps']} grasps held out) | "
            f"{h['mae_n']:.2f} ({_times(h['ratio_to_constant'])}x the constant) | {e['zero_shot_mae_n']:.2f} | "
            f"{h['constant_mae_n']:.2f} (training grasps' mean) |"]
    gh = g["held_out"]
    if gh is None:
        rows.append("| generator | no held-out pair with |ΔFz| >= 1.5 N | | |")
    else:
        rows.append(f"| generator MSE ÷ a copy's ({gh['pairs']} pairs, {gh['grasps']} grasps) | "
                    f"{gh['ratio_to_copy']:.2f} | {gh['zero_shot_ratio_to_copy']:.2f} | 1 (the reference copied) |")
    return "\n".join(rows) + "\n\n" + grasp_table(h["per_grasp"])


def _times(ratio: float | None) -> str:
    """A ratio to the constant, or "–" where the constant's error is 0 and none exists."""
    return "–" if ratio is None else f"{ratio:.2f}"


def grasp_table(rows: list[dict]) -> str:
    """The estimator per held-out grasp (markdown): its frames, Fz MAE and the constant's, their ratio."""
    lines = ["| held-out grasp | frames | estimator Fz MAE, N | constant's, N | ratio |", "| --- | --- | --- | --- | --- |"]
    lines += [f"| {r['grasp']} | {r['frames']} | {r['mae_n']:.2f} | {r['constant_mae_n']:.2f} | "
              f"{_times(r['ratio'])}{'' if r['mae_n'] < r['constant_mae_n'] else ' (worse)'} |" for r in rows]
    return "\n".join(lines)


def card(record: dict) -> str:
    """The bundle's README.md."""
    e, g = record["estimator"], record["generator"]
    rule = ("used only where the upper end of the interval is below 1 and it beats the constant on most held-out "
            "grasps")
    return (f"# Sensor calibration bundle\n\nFrom {record['images']} labelled frames in `{record['presses']}`.\n\n"
            f"**{e['held_out']['decision']['why']}** (the rule: {rule}).\n\n{table(record)}\n\n"
            f"- estimator: {e['base']} ({e['base_hash']}), {e['method']}, {e['steps']} steps.\n"
            f"- generator: {g['base']} ({g['base_hash']}) fine-tuned on {g['train_images']} frames: autoencoder "
            f"{g['ae_steps']} steps, DiT {g['dit_steps']} steps, peak LR {g['lr']}.\n"
            "- `report.png`: estimated against true Fz per held-out grasp; real and generated frames at three ΔF.\n")


def _generated_row(record: dict, ds, generator_dir: Path):
    """(real frames, generated frames, ΔFz) of the first held-out grasp: its lowest-force frame as the reference."""
    from controltac_il.generator import ForceGenerator
    from controltac_il.generator.forces import VALIDATED_RANGE
    from controltac_il.tactile.residual import from_residual

    rows = record["generator"]["held_out_rows"]
    rec = ds.records[rows[0]]
    grasp = [i for i in rows if (ds.records[i].object, ds.records[i].pose_id) == (rec.object, rec.pose_id)]
    f = ds.forces()
    ref = min(grasp, key=lambda i: f[i, 2])
    targets = [float(np.clip(f[ref, 2] + d, *VALIDATED_RANGE.fz)) for d in REPORT_DFZ]
    real = [min(grasp, key=lambda i: abs(f[i, 2] - t)) for t in targets]
    delta = np.array([[0.0, 0.0, t - f[ref, 2]] for t in targets], np.float32)
    generator = ForceGenerator.from_pretrained(generator_dir)
    f_ref = generator.condition_reference(np.repeat(f[ref][None], len(delta), 0))
    gen = generator.generate(np.stack([ds.residual(ref)] * len(delta)), delta, seed=0, reference_force=f_ref)
    bg = ds.background_of(ref)
    return ([ds.image(i) for i in real], [from_residual(g, bg) for g in gen], [f[i, 2] for i in real],
            delta[:, 2] + f[ref, 2], ds.image(ref), f[ref, 2])


def save_report(path: Path, record: dict, ds, generator_dir: Path) -> Path:
    """``report.png``: left, held-out estimated vs true Fz coloured by grasp; right, the reference, real frames
    and generated frames at three ΔF of a held-out grasp."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    e = record["estimator"]
    fig = plt.figure(figsize=(13, 4.6))
    ax = fig.add_subplot(1, 3, 1)
    true, grasp = np.array(e["true_fz"]), np.array(e["grasp_of_frame"])
    pred = np.array([np.nan if v is None else v for v in e["held_out"]["predicted_fz"]], float)  # None: trained on
    for g in np.unique(grasp[np.isfinite(pred)]):
        m = (grasp == g) & np.isfinite(pred)
        ax.plot(true[m], pred[m], "o-", ms=3, lw=0.8)
    lim = [0, max(true.max(), np.nanmax(pred)) * 1.05]
    ax.plot(lim, lim, "k--", lw=0.8)
    ax.set(xlabel="true Fz (N)", ylabel="estimated Fz, held out (N)", xlim=lim, ylim=lim,
           title=f"estimator: MAE {e['held_out']['mae_n']:.2f} N vs constant {e['held_out']['constant_mae_n']:.2f} N")
    if record["generator"]["held_out_rows"]:
        real, gen, real_fz, gen_fz, ref, ref_fz = _generated_row(record, ds, generator_dir)
        grid = fig.add_gridspec(2, 4, left=0.4, right=0.99, wspace=0.05, hspace=0.25)
        for r, (frames, forces, name) in enumerate(((real, real_fz, "real"), (gen, gen_fz, "generated"))):
            a = fig.add_subplot(grid[r, 0])
            a.imshow(ref), a.set_title(f"reference {ref_fz:.1f} N", fontsize=8), a.axis("off")
            for c, (img, fz) in enumerate(zip(frames, forces)):
                a = fig.add_subplot(grid[r, c + 1])
                a.imshow(img), a.set_title(f"{name} {fz:.1f} N", fontsize=8), a.axis("off")
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
