"""The end-to-end job: collect demos in the MuJoCo scene -> ForceAugment -> train ACT -> deploy in the scene.

    from controltac_il.pipeline import run_pipeline
    report = run_pipeline(out="out/pipeline")          # embedded default, cpu preset

Every stage is timed; the deployment stage runs the same ControlLoop as the robot (sim robot, virtual
clock) and reports the success rate with its Wilson 95 % interval. Demos and augmentation caches are
kept under the cache folder ($CONTROLTAC_CACHE or ~/.cache/controltac_il) and reused when complete.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from controltac_il.io import atomic_dir, write_json

Z_95 = 1.959963984540054


def wilson_interval(successes: int, trials: int, z: float = Z_95) -> tuple[float, float]:
    """Wilson score interval (low, high) of a success rate; (0, 1) when there are no trials."""
    if trials < 0 or not 0 <= successes <= trials:
        raise ValueError(f"need 0 <= successes <= trials, got successes={successes}, trials={trials}")
    if trials == 0:
        return 0.0, 1.0
    p = successes / trials
    denom = 1 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denom
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def cache_root() -> Path:
    """$CONTROLTAC_CACHE, else $XDG_CACHE_HOME/controltac_il, else ~/.cache/controltac_il."""
    base = os.environ.get("CONTROLTAC_CACHE")
    if base:
        return Path(base)
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "controltac_il"


def scene_fingerprint() -> str:
    """Short hash of everything that shapes a recorded demo: the scene's MJCF, its code and the expert."""
    import envs

    h = hashlib.sha1()
    root = Path(envs.__file__).resolve().parent
    for path in sorted([*root.glob("*.py"), *root.glob("assets/*")]):
        h.update(path.name.encode())
        h.update(path.read_bytes())
    from controltac_il.tactile import optics, sensor

    for module in (optics, sensor):
        h.update(Path(module.__file__).read_bytes())
    return h.hexdigest()[:10]


def default_demos(episodes: int = 20, seed: int = 0, root: str | Path | None = None, scene: str = "default") -> Path:
    """Folder of ``episodes`` scripted-expert peg-in-hole demos (collected once, then reused).

    scene: "default" or "touch_critical" (``envs.config.SCENES``).

    The cache folder is keyed by the scene's fingerprint, so demos recorded by an older scene are
    never reused. Written atomically: an interrupted collection leaves no half folder behind.
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    prefix = "peg_in_hole" if scene == "default" else f"peg_in_hole_{scene}"
    name = f"{prefix}-n{episodes}-seed{seed}-{scene_fingerprint()}"
    folder = Path(root) if root is not None else cache_root() / "demos" / name
    info = folder / "collect_info.json"
    if info.is_file():
        try:
            if json.loads(info.read_text()).get("episodes") == episodes:
                return folder
        except (OSError, json.JSONDecodeError):
            pass
    from envs import collect

    with atomic_dir(folder) as tmp:
        code = collect.main(["--episodes", str(episodes), "--out", str(tmp), "--seed", str(seed), "--scene", scene])
        if code != 0:
            raise RuntimeError(f"demo collection failed (exit code {code}); see the messages above")
    return folder


class ForceAugmentStage:
    """``train_set -> ForceAugment(train_set)``: K generated copies of every training episode.

    The cache holds ``max_copies`` copies; asking for fewer uses the first K of them (every draw is a
    pure function of (seed, episode, copy, frame), so copy k is the same whatever K is).
    """

    def __init__(self, copies: int, generator: str | Path | None = None, seed: int = 0,
                 max_copies: int | None = None, steps: int | None = None, cache_dir: str | Path | None = None,
                 **settings):
        """settings: other ``ForceAugmentConfig`` fields (e.g. ``offset_range``, ``out_of_range``); the
        description names only those that differ from the defaults (older runs stay comparable)."""
        if not 1 <= copies <= 9:
            raise ValueError(f"copies must be in 1..9 (the paper's range), got {copies}")
        self.copies, self.generator, self.seed, self.steps = copies, generator, seed, steps
        self.max_copies = max(copies, max_copies or copies)
        self.cache_dir = cache_dir
        from controltac_il.augment import ForceAugmentConfig
        from controltac_il.generator.checkpoint import checkpoint_hash
        from controltac_il.generator.pipeline import locate_checkpoint

        ForceAugmentConfig(**settings)  # a bad field fails here, naming it, before any work
        defaults = ForceAugmentConfig()
        self.settings = {k: v for k, v in settings.items() if getattr(ForceAugmentConfig(**{k: v}), k) != getattr(defaults, k)}
        self.description = {"kind": "force", "copies": copies, "generator": str(generator or "shipped"),
                            "generator_hash": checkpoint_hash(locate_checkpoint(generator)),
                            "seed": seed, "steps": steps,
                            **{k: list(v) if isinstance(v, tuple) else v for k, v in self.settings.items()}}

    def __call__(self, train_set):
        from torch.utils.data import Subset

        from controltac_il.augment import ForceAugment
        from controltac_il.generator import ForceGenerator

        gen = ForceGenerator.from_pretrained(self.generator)
        aug = ForceAugment(train_set, gen, copies=self.max_copies, seed=self.seed, steps=self.steps,
                           cache_dir=self.cache_dir, **self.settings)
        self.description["summary"] = aug.summary()
        n = len(train_set)
        return aug if self.copies == self.max_copies else Subset(aug, range((self.copies + 1) * n))


def make_augment(copies: int, generator: str | Path | None = None, seed: int = 0, **kwargs) -> ForceAugmentStage:
    """The ForceAugment stage used by ``train_act.py --augment force``."""
    return ForceAugmentStage(copies, generator, seed, **kwargs)


@dataclass
class PipelineConfig:
    """The main job's sizes (defaults: the embedded default, < 15 min on 2 cores).

    demos: scripted demos collected in the scene. copies: ForceAugment copies (0 = real only).
    steps / batch_size: ACT training (cpu preset). eval_episodes: seeded deployment episodes.
    eval_seed: first scene seed of the evaluation (disjoint from the demos' seeds).
    generator: generator checkpoint (None = shipped). seed: training / augmentation seed.
    """

    demos: int = 20
    copies: int = 1
    steps: int = 1500
    batch_size: int = 16
    eval_episodes: int = 10
    eval_seed: int = 100_000
    generator: str | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("demos", "steps", "batch_size", "eval_episodes"):
            if getattr(self, name) < 1:
                raise ValueError(f"PipelineConfig.{name} must be >= 1, got {getattr(self, name)}")
        if not 0 <= self.copies <= 9:
            raise ValueError(f"PipelineConfig.copies must be in 0..9, got {self.copies}")


def run_pipeline(out: str | Path = "out/pipeline", config: PipelineConfig | None = None,
                 progress: bool = True) -> dict:
    """Collect -> augment -> train -> deploy; prints and returns the report (also ``out/pipeline.json``)."""
    from policies.act.training import TrainConfig, train_on_folder

    cfg = config or PipelineConfig()
    out = Path(out)
    times: dict[str, float] = {}
    t = time.perf_counter()
    demos = default_demos(cfg.demos, seed=cfg.seed)
    times["collect"] = time.perf_counter() - t
    print(f"[collect] {cfg.demos} demos in {demos} ({times['collect']:.1f} s)")

    augment = make_augment(cfg.copies, cfg.generator, cfg.seed) if cfg.copies else None
    t = time.perf_counter()
    train_config = TrainConfig(steps=cfg.steps, batch_size=cfg.batch_size, seed=cfg.seed,
                               val_every=max(cfg.steps // 4, 1))

    def timed_augment(ds):  # time the augmentation stage apart from training
        t0 = time.perf_counter()
        res = augment(ds)
        times["augment"] = time.perf_counter() - t0
        print(f"[augment] {cfg.copies} ForceAugment cop{'y' if cfg.copies == 1 else 'ies'}: "
              f"{augment.description.get('summary')} ({times['augment']:.1f} s)")
        return res

    if augment is not None:
        timed_augment.description = augment.description
    summary = train_on_folder(demos, out / "act", preset="cpu", train_config=train_config,
                              augment=timed_augment if augment is not None else None, progress=progress)
    times["train"] = time.perf_counter() - t - times.get("augment", 0.0)
    print(f"[train] {summary['steps']} steps, {summary['samples_per_s']:.1f} samples/s ({times['train']:.1f} s)")

    from policies.act.deploy import evaluate_in_sim

    t = time.perf_counter()
    result = evaluate_in_sim(out / "act", episodes=cfg.eval_episodes, seed=cfg.eval_seed, progress=progress)
    times["deploy"] = time.perf_counter() - t
    lo, hi = result["wilson95"]
    print(f"[deploy] success {result['successes']}/{result['episodes']} = {result['success_rate']:.0%} "
          f"(Wilson 95 % [{lo:.0%}, {hi:.0%}]) ({times['deploy']:.1f} s)")
    report = {"config": asdict(cfg), "demos": str(demos), "training": summary, "evaluation": result,
              "seconds": {**times, "total": sum(times.values())}}
    write_json(out / "pipeline.json", report)
    print("time per stage (s): " + ", ".join(f"{k} {v:.1f}" for k, v in report["seconds"].items()))
    return report
