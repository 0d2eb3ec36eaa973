"""From a folder of episodes to ACT's training and validation sets (split by episode).

The ACT config's data fields (cameras, tactile sensors, state and action sizes) are read from the
episodes; a checkpoint used with other data is checked against them with a clear error.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from torch.utils.data import Dataset

from controltac_il.datasets import EpisodeDataset, EpisodeSubset
from controltac_il.datasets.background import episode_background_digests
from controltac_il.lerobot import LeRobotEpisodes
from controltac_il.streams import LOOP, image_key, tactile_key
from policies.act.configuration_act import ACTConfig


@dataclass
class DataSpec:
    """What the episodes hold: camera and tactile names, qpos size D and action size A."""

    camera_names: tuple[str, ...]
    tactile_names: tuple[str, ...]
    state_dim: int
    action_dim: int

    @classmethod
    def of(cls, ds: EpisodeDataset) -> "DataSpec":
        return cls(tuple(ds.cameras), tuple(ds.tactile_sensors), int(ds.stats["qpos"]["mean"].shape[0]),
                   int(ds.stats["action"]["mean"].shape[0]))


def check_compatible(config: ACTConfig, spec: DataSpec, where: str = "dataset") -> None:
    """Raise ValueError when data described by ``spec`` lacks what ``config`` expects."""
    missing = [image_key(c, LOOP) for c in config.camera_names if c not in spec.camera_names]
    missing += [tactile_key(s, LOOP) for s in config.tactile_names if s not in spec.tactile_names]
    if missing:
        raise ValueError(f"{where} is missing {missing} that the checkpoint expects (it has cameras "
                         f"{list(spec.camera_names)}, tactile sensors {list(spec.tactile_names)})")
    if spec.action_dim != config.action_dim:
        raise ValueError(f"{where} has actions of dimension {spec.action_dim}, the checkpoint expects "
                         f"{config.action_dim}")
    if spec.state_dim != config.state_dim:
        raise ValueError(f"{where} has qpos of dimension {spec.state_dim}, the checkpoint expects {config.state_dim}")


def split_by_episode(ds: EpisodeDataset, val_fraction: float, seed: int = 0,
                     recorded: dict[int, int] | None = None) -> tuple[list[int], list[int]]:
    """Frame indices of (train, validation) with whole recorded episodes held out; no validation for 1 episode.

    recorded: {episode: the recorded episode it is or is a generated copy of} (LeRobotEpisodes'; None: every
    episode is recorded). A held-out episode's copies are in neither set: training never sees a copy of a
    validation episode, and validation is on recorded frames only."""
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction!r}")
    episodes, _ = ds.frame_table()
    if recorded is not None:
        lookup = {int(e): recorded[int(e)] for e in np.unique(episodes)}
        source = np.array([lookup[int(e)] for e in episodes], dtype=np.int64)
    else:
        source = np.asarray(episodes)
    ids = np.unique(source)
    n_val = int(round(val_fraction * len(ids))) if len(ids) > 1 else 0
    if val_fraction > 0 and len(ids) > 1:
        n_val = max(n_val, 1)
    val_ids = set(np.random.default_rng(seed).permutation(ids)[:n_val].tolist())
    is_val = np.isin(source, list(val_ids))
    return np.flatnonzero(~is_val).tolist(), np.flatnonzero(is_val & (source == episodes)).tolist()


@dataclass
class TrainingData:
    """Everything the training loop needs from a dataset folder."""

    train: Dataset
    val: Dataset | None
    spec: DataSpec
    stats: dict
    backgrounds: dict[str, np.ndarray]  # episode 0's, per sensor: the policy's own (its checkpoint keeps it)
    background_digests: dict[str, str]  # every episode's, per sensor (``episode_background_digests``)
    n_episodes: int
    val_episodes: int
    longest_episode: int = 0


def load_training_data(root: str | Path, chunk_size: int, val_fraction: float = 0.1, seed: int = 0,
                       stats_path: str | Path | None = None, tactile_sensors=None,
                       data_options: dict | None = None) -> TrainingData:
    """Open ``root`` (a folder of ACT episodes: :class:`EpisodeDataset`; a LeRobot v3.0 folder, with
    ``meta/info.json``: :class:`LeRobotEpisodes`, its default tactile and force keys) and split it by episode.

    tactile_sensors: the tactile streams to train on (None = all; () = none, a vision-only policy).
    data_options: how to read it: a LeRobot folder's ``tactile_keys`` / ``force_keys``, and for either kind
        ``background_images`` {tactile sensor: image file} (None: the defaults)."""
    options = dict(data_options or {})
    unknown = sorted(set(options) - {"tactile_keys", "force_keys", "background_images"})
    if unknown:
        raise ValueError(f"data_options: unknown {unknown}; expected tactile_keys, force_keys, background_images")
    if (Path(root) / "meta" / "info.json").is_file():
        ds = LeRobotEpisodes(root, chunk_size=chunk_size, tactile_sensors=tactile_sensors, **options)
    elif set(options) - {"background_images"}:
        raise ValueError(f"tactile_keys / force_keys: only for a LeRobot v3.0 folder; {root} has no meta/info.json")
    else:
        ds = EpisodeDataset(root, chunk_size=chunk_size, stats_path=stats_path, tactile_sensors=tactile_sensors,
                            **options)
    train_idx, val_idx = split_by_episode(ds, val_fraction, seed, getattr(ds, "recorded_episode", None))
    episodes, _ = ds.frame_table()
    stats = {k: {m: np.asarray(v).astype(float).tolist() for m, v in d.items()} for k, d in ds.stats.items()}
    backgrounds = {s: np.asarray(ds.backgrounds[(0, s)]) for s in ds.tactile_sensors}
    return TrainingData(
        train=EpisodeSubset(ds, train_idx), val=EpisodeSubset(ds, val_idx) if val_idx else None, spec=DataSpec.of(ds),
        stats=stats, backgrounds=backgrounds, background_digests=episode_background_digests(ds.backgrounds),
        n_episodes=len(np.unique(episodes)),
        val_episodes=len(np.unique(episodes[val_idx])) if val_idx else 0,
        longest_episode=int(np.bincount(np.unique(episodes, return_inverse=True)[1]).max()) if len(episodes) else 0)
