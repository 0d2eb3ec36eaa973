"""``train_act.py``'s job: train ACT on a folder of episodes (default: the scene's demos), optionally
with ForceAugment copies of every training episode."""

from __future__ import annotations

from pathlib import Path

from controltac_il.augment import ForceAugmentStage
from controltac_il.app.demos import default_demos
from envs.config import DEMO_EPISODES
from policies.act.training import ACTTrainConfig, train_on_folder


def train_act(out: str | Path, dataset: str | Path | None = None, *, demos: int = DEMO_EPISODES, preset: str = "cpu",
              train_config: ACTTrainConfig | None = None, copies: int = 0, generator: str | Path | None = None,
              val_fraction: float = 0.1, chunk_size: int = 20, resume: bool = False, overwrite: bool = False,
              progress: bool = True, data_options: dict | None = None) -> dict:
    """Train into ``out`` (``last/``, ``best/``, ``train_log.json``); returns the training summary.

    dataset: folder of ``episode_<i>.hdf5``; None collects (or reuses) ``demos`` scripted demos.
    copies: ForceAugment copies per training episode (0 = real data only), drawn with the training seed.
    data_options: how to read ``dataset`` (``policies.act.data.load_training_data``): a LeRobot v3.0 folder's
        {"tactile_keys": [...], "force_keys": {...}}, for either kind "background_images" (None: the defaults).
    resume / overwrite: continue the run in ``out`` / replace it (only what the training wrote); without
    either, an ``out`` holding a run is refused (``policies.act.training.train``).
    """
    train_config = train_config or ACTTrainConfig()
    if dataset is None:
        dataset = default_demos(demos)
    augment = ForceAugmentStage(copies, generator, seed=train_config.seed) if copies else None
    return train_on_folder(dataset, out, preset=preset, train_config=train_config, val_fraction=val_fraction,
                           augment=augment, resume=resume, overwrite=overwrite, chunk_size=chunk_size,
                           progress=progress, data_options=data_options)
