"""The main job on the embedded default (``python -m controltac_il``, what ``./run.sh`` runs).

Renders a contact sheet of the sensor model (every object at 1, 3, 6, 10 N), then collects scripted
demos in the MuJoCo scene -> ForceAugment (shipped generator) -> trains ACT with the cpu preset ->
deploys through the robot's control loop (simulated robot, virtual clock) -> success rate with its
Wilson 95 % interval and the time per stage. Demos and augmentation caches are kept under
``controltac_il.io.cache_root()`` and reused when complete.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

from controltac_il.app.deploy import evaluate_in_sim
from controltac_il.app.demos import default_demos
from controltac_il.app.job_config import PipelineConfig
from controltac_il.app.train import train_act
from controltac_il.io import write_json
from controltac_il.tactile import HELDOUT_OBJECTS, TRAIN_OBJECTS, TactileSensor
from controltac_il.tactile.sheet import contact_sheet, save_png
from envs.config import EVAL_SEED
from policies.act.training import ACTTrainConfig

SHEET_FORCES = (1.0, 3.0, 6.0, 10.0)  # N, the contact sheet's columns


def render_contact_sheet(out: Path) -> Path:
    """The sensor model's contact sheet (every object at SHEET_FORCES) as ``out/contact_sheet.png``."""
    t0 = time.perf_counter()
    objects = TRAIN_OBJECTS + HELDOUT_OBJECTS
    path = save_png(out / "contact_sheet.png", contact_sheet(TactileSensor(), objects, SHEET_FORCES)[::2, ::2])
    print(f"[sensor] contact sheet, {len(objects)} objects × forces {SHEET_FORCES} N: {path} "
          f"({time.perf_counter() - t0:.1f} s)")
    return path


def run_pipeline(out: str | Path = "out/pipeline", config: PipelineConfig | None = None,
                 progress: bool = True) -> dict:
    """Collect -> augment -> train -> deploy; prints and returns the report (also ``out/pipeline.json``)."""
    cfg = config or PipelineConfig()
    out = Path(out)
    times: dict[str, float] = {}
    t = time.perf_counter()
    demos = default_demos(cfg.demos, seed=cfg.seed)
    times["collect"] = time.perf_counter() - t
    print(f"[collect] {cfg.demos} demos in {demos} ({times['collect']:.1f} s)")

    t = time.perf_counter()
    train_config = ACTTrainConfig(steps=cfg.steps, batch_size=cfg.batch_size, seed=cfg.seed,
                               val_every=max(cfg.steps // 4, 1))
    summary = train_act(out / "act", demos, train_config=train_config, copies=cfg.copies,
                        generator=cfg.generator, progress=progress)
    if summary.get("augment"):
        times["augment"] = summary["augment"]["summary"]["seconds"]
        print(f"[augment] {augment_sentence(cfg.copies, summary['augment']['summary'])} ({times['augment']:.1f} s)")
    times["train"] = time.perf_counter() - t - times.get("augment", 0.0)
    print(f"[train] {summary['steps']} steps, {summary['samples_per_s']:.1f} samples/s ({times['train']:.1f} s)")

    t = time.perf_counter()
    result = evaluate_in_sim(out / "act", episodes=cfg.eval_episodes, seed=EVAL_SEED, progress=progress)
    times["deploy"] = time.perf_counter() - t
    lo, hi = result["wilson95"]
    print(f"[deploy] success {result['successes']}/{result['episodes']} = {result['success_rate']:.0%} "
          f"(Wilson 95 % [{lo:.0%}, {hi:.0%}]) ({times['deploy']:.1f} s)")
    report = {"config": asdict(cfg), "demos": str(demos), "training": summary, "evaluation": result,
              "seconds": {**times, "total": sum(times.values())}}
    write_json(out / "pipeline.json", report)
    print("time per stage (s): " + ", ".join(f"{k} {v:.1f}" for k, v in report["seconds"].items()))
    return report


def augment_sentence(copies: int, counts: dict) -> str:
    """ForceAugment's summary counts (``ForceAugment.summary``) as a sentence."""
    return (f"{copies} ForceAugment cop{'y' if copies == 1 else 'ies'}: {counts['tactile_frames']} tactile frames, "
            f"{counts['regenerated'] + counts['clamped']} generated ({counts['clamped']} of them at a target clamped "
            f"to the validated range), {counts['no_contact']} without contact kept as recorded, "
            f"{counts['skipped']} skipped")
