"""ACT training dataset over a folder of episodes (``episode_<i>.hdf5``).

Index ``i`` runs over every frame of every episode (LeRobot convention). An item is the frame's
observations plus the action chunk that starts at it::

    episode_index                          int
    frame_index                            int
    observation.qpos                       float32 (D,)
    observation.images.<camera>            uint8 (3, H, W)
    observation.tactile.<sensor>           uint8 (3, H, W)
    observation.tactile_background.<sensor> uint8 (3, H, W)
    observation.force.<sensor>             float32 (3,)   only when the episodes carry force labels
    action                                 float32 (chunk_size, A) actions t .. t+chunk_size-1
    action_is_pad                          bool (chunk_size,) True past the episode's end

Past the end the chunk repeats the last action (masked by ``action_is_pad``). qpos and action are
returned as recorded; ``dataset.stats`` holds their mean/std (computed once over all frames and saved
as JSON outside the data folder) for the policy to normalise with. Files are opened read-only.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from pathlib import Path

import h5py
import numpy as np
import torch
from torch.utils.data import Dataset, Subset

from controltac_il.arrays import as_index
from controltac_il.config import is_int
from controltac_il.datasets.background import estimate_background, given_backgrounds, image_digests
from controltac_il.datasets.checks import (ACTION, QPOS, check_episode, check_same_layout, check_same_streams, layout,
                                           open_episode, stream_path, streams)
from controltac_il.datasets.episodes import episode_index, episode_paths
from controltac_il.io import cache_root, write_json
from controltac_il.streams import HDF5, HDF5_STATE, background_key, force_key, image_key, tactile_key

STD_FLOOR = 1e-2  # ACT's floor on the std used for normalisation (avoids dividing by ~0)


STATS_WRITER = "controltac_il.datasets.EpisodeDataset"  # stamped in every stats file this class writes


def default_stats_dir() -> Path:
    """Folder for normalisation stats: ``controltac_il.io.cache_root() / "stats"``."""
    return cache_root() / "stats"


def _own_stats_file(path: Path) -> bool:
    """True when ``path`` is a stats file this class wrote (it may then be replaced)."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    legacy = {"fingerprint", "std_floor", "qpos", "action"} <= set(doc) if isinstance(doc, dict) else False
    return isinstance(doc, dict) and (doc.get("written_by") == STATS_WRITER or legacy)


class EpisodeDataset(Dataset):
    """Frames of a folder of ACT episodes with their padded action chunks.

    Args:
        root: folder with ``episode_<i>.hdf5`` files (never written to).
        chunk_size: actions per item (ACT's N_a), >= 1.
        cameras: camera names to return; None = all cameras of the first episode.
        tactile_sensors: tactile sensor names to return; None = all of the first episode.
        stats_path: JSON file for the qpos/action mean and std; None = a file named after the folder in
            ``default_stats_dir()``. Recomputed when the episode files change (see ``fingerprint``).
        background_images: {tactile sensor (or its key observation.tactile.<s>): path of an RGB image file of it
            at rest}: its background in every episode, in place of the recorded or estimated one.
    """

    def __init__(self, root, chunk_size: int = 20, cameras=None, tactile_sensors=None, stats_path=None,
                 background_images=None):
        if not is_int(chunk_size) or chunk_size < 1:
            raise ValueError(f"chunk_size: expected an int >= 1, got {chunk_size!r}")
        self.root = Path(root).resolve()
        self.chunk_size = int(chunk_size)
        self.paths = episode_paths(self.root)
        if not self.paths:
            raise ValueError(f"root: no episode_<i>.hdf5 files in {self.root}")
        self.episode_ids = [episode_index(p) for p in self.paths]
        lengths, backgrounds, self._digests, first_layout = [], {}, [], None
        for n, p in enumerate(self.paths):
            with open_episode(p) as f:
                lengths.append(check_episode(f, p))
                if n == 0:
                    self.cameras = self._select("cameras", cameras, streams(f, "images"))
                    self.tactile_sensors = self._select("tactile_sensors", tactile_sensors, streams(f, "tactile"))
                    self.force_sensors = [s for s in streams(f, "force") if s in self.tactile_sensors]
                for group, names, exact in (("images", self.cameras, cameras is None),
                                            ("tactile", self.tactile_sensors, tactile_sensors is None)):
                    check_same_streams(p, self.paths[0], group, names, streams(f, group), exact)
                found_force = [s for s in streams(f, "force") if s in self.tactile_sensors]
                check_same_streams(p, self.paths[0], "force", self.force_sensors, found_force, exact=True)
                here = layout(f, self.cameras, self.tactile_sensors)
                first_layout = here if n == 0 else first_layout
                check_same_layout(p, self.paths[0], first_layout, here)
                trajectory = f[QPOS][()].tobytes() + f[ACTION][()].tobytes()
                self._digests.append(hashlib.sha256(trajectory).hexdigest()[:16])
                for s in self.tactile_sensors:
                    key = stream_path("tactile_background", s)
                    backgrounds[(n, s)] = f[key][()] if key in f else None
        self.lengths = np.asarray(lengths, dtype=np.int64)
        self.offsets = np.concatenate([[0], np.cumsum(self.lengths)])
        given = given_backgrounds(background_images, {s: (tactile_key(s, HDF5),) for s in self.tactile_sensors},
                                  {s: first_layout[stream_path("tactile", s)][:2] for s in self.tactile_sensors})
        self._given = image_digests(given)
        self.backgrounds = self._fill_backgrounds({(n, s): given.get(s, bg) for (n, s), bg in backgrounds.items()})
        self.stats_path = Path(stats_path) if stats_path is not None else self._default_stats_path()
        self.stats = self._load_or_compute_stats()
        self._files: dict[int, dict] = {}
        self._pid = None

    @staticmethod
    def _select(field: str, wanted, available: list[str]) -> list[str]:
        if wanted is None:
            return list(available)
        if not isinstance(wanted, (str, list, tuple)):
            raise ValueError(f"{field}: expected a name or a list of names, got {wanted!r}")
        wanted = [wanted] if isinstance(wanted, str) else list(wanted)
        unknown = [w for w in wanted if w not in available]
        if unknown:
            raise ValueError(f"{field}: unknown name {unknown[0]!r}; the episodes have {available}")
        return wanted

    def _fill_backgrounds(self, found: dict) -> dict:
        out = {}
        for (n, s), bg in found.items():
            if bg is None:
                with h5py.File(self.paths[n], "r") as f:
                    frames = f[stream_path("tactile", s)][()]
                    fkey = stream_path("force", s)
                    force = f[fkey][()] if fkey in f else None
                bg, used = estimate_background(frames, force)
                warnings.warn(
                    f"{self.paths[n].name}: no tactile background for sensor {s!r}; estimated from "
                    f"{len(used)} frame(s) of the episode taken as no-contact",
                    stacklevel=3,
                )
            out[(n, s)] = bg
        return out

    # --- normalisation statistics -------------------------------------------------------------
    def fingerprint(self) -> dict:
        """Identity of the data: per episode file name, size, modification time (ns), length and a
        digest of its qpos and actions; the given background images' pixels' digests.

        Size and length alone do not tell a re-recorded folder from the old one (episodes of a
        fixed-length task match byte for byte in size); the trajectory digest and mtime do."""
        files = []
        for p, n, digest in zip(self.paths, self.lengths, self._digests):
            st = p.stat()
            files.append([p.name, st.st_size, st.st_mtime_ns, int(n), digest])
        given = {"background_images": self._given} if self._given else {}  # they change the items
        return {"root": str(self.root), "files": files, **given}

    def _default_stats_path(self) -> Path:
        digest = hashlib.sha256(str(self.root).encode()).hexdigest()[:16]
        return default_stats_dir() / f"{self.root.name}-{digest}.json"

    def _load_or_compute_stats(self) -> dict:
        fp = self.fingerprint()
        if self.stats_path.is_file():
            try:
                doc = json.loads(self.stats_path.read_text())
                if doc.get("fingerprint") == fp:
                    return {k: {m: np.asarray(v, np.float32) for m, v in doc[k].items()} for k in ("qpos", "action")}
            except (OSError, json.JSONDecodeError, KeyError, TypeError):
                pass
        if self.root in self.stats_path.resolve().parents:
            raise ValueError(f"stats_path: must not be inside the data folder {self.root}")
        if self.stats_path.exists() and not _own_stats_file(self.stats_path):
            raise ValueError(f"stats_path: {self.stats_path} exists and is not a stats file written by EpisodeDataset; "
                             "refusing to overwrite it (pass a new path)")
        qpos, action = [], []
        for p in self.paths:
            with open_episode(p) as f:
                qpos.append(f[QPOS][()])
                action.append(f[ACTION][()])
        stats = {}
        for name, parts in (("qpos", qpos), ("action", action)):
            arr = np.concatenate(parts).astype(np.float64)
            stats[name] = {"mean": arr.mean(0).astype(np.float32),
                           "std": np.maximum(arr.std(0), STD_FLOOR).astype(np.float32)}
        write_json(self.stats_path, {
            "written_by": STATS_WRITER,
            "fingerprint": fp,
            "std_floor": STD_FLOOR,
            **{k: {m: v.tolist() for m, v in d.items()} for k, d in stats.items()},
        })
        return stats

    # --- indexing -----------------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.offsets[-1])

    def locate(self, index: int) -> tuple[int, int]:
        """(position of the episode in ``self.paths``, frame) of dataset index ``index``."""
        if not -len(self) <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} frames")
        index = index % len(self)
        n = int(np.searchsorted(self.offsets, index, side="right") - 1)
        return n, int(index - self.offsets[n])

    def frame_table(self) -> tuple[np.ndarray, np.ndarray]:
        """(episode_index, frame_index) of every dataset index, without reading images."""
        ep = np.repeat(np.asarray(self.episode_ids, dtype=np.int64), self.lengths)
        fr = np.concatenate([np.arange(n, dtype=np.int64) for n in self.lengths])
        return ep, fr

    def _handles(self, n: int) -> dict:
        """Open h5py datasets of episode ``n`` (file opened read-only once per process)."""
        if self._pid != os.getpid():  # handles do not survive fork: reopen in each worker
            self._files, self._pid = {}, os.getpid()
        h = self._files.get(n)
        if h is None:
            f = h5py.File(self.paths[n], "r")
            h = {"file": f, "action": f[ACTION], "qpos": f[QPOS]}
            h.update({f"images.{c}": f[stream_path("images", c)] for c in self.cameras})
            h.update({f"tactile.{s}": f[stream_path("tactile", s)] for s in self.tactile_sensors})
            h.update({f"force.{s}": f[stream_path("force", s)] for s in self.force_sensors})
            self._files[n] = h
        return h

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_files"], state["_pid"] = {}, None
        return state

    def __getitem__(self, index: int) -> dict:
        return self.item(index)

    def item(self, index: int, skip_keys=()) -> dict:
        """Item ``index``; keys in ``skip_keys`` (e.g. a tactile image about to be replaced) are not read."""
        n, t = self.locate(as_index(index, "EpisodeDataset"))
        h = self._handles(n)
        T = int(self.lengths[n])
        stop = min(t + self.chunk_size, T)
        chunk = h["action"][t:stop]
        pad = self.chunk_size - len(chunk)
        if pad:
            chunk = np.concatenate([chunk, np.repeat(chunk[-1:], pad, axis=0)])
        is_pad = np.zeros(self.chunk_size, dtype=bool)
        is_pad[self.chunk_size - pad:] = True
        item = {
            "episode_index": self.episode_ids[n],
            "frame_index": t,
            HDF5_STATE: torch.from_numpy(h["qpos"][t]),
        }
        for cam in self.cameras:
            item[image_key(cam, HDF5)] = torch.from_numpy(h[f"images.{cam}"][t]).permute(2, 0, 1)
        for s in self.tactile_sensors:
            if tactile_key(s, HDF5) not in skip_keys:
                item[tactile_key(s, HDF5)] = torch.from_numpy(h[f"tactile.{s}"][t]).permute(2, 0, 1)
            item[background_key(s, HDF5)] = torch.from_numpy(self.backgrounds[(n, s)]).permute(2, 0, 1)
        for s in self.force_sensors:
            item[force_key(s, HDF5)] = torch.from_numpy(h[f"force.{s}"][t])
        item["action"] = torch.from_numpy(np.ascontiguousarray(chunk, dtype=np.float32))
        item["action_is_pad"] = torch.from_numpy(is_pad)
        return item


class EpisodeSubset(Subset):
    """A Subset of an EpisodeDataset or LeRobotEpisodes (whole episodes: a train / validation split) that keeps
    ``frame_table()`` and ``fingerprint()``."""

    def fingerprint(self) -> dict:
        """The dataset's fingerprint and a digest of the subset's indices (a cache of one split is not another's)."""
        index = np.asarray(self.indices, np.int64).tobytes()
        return {**self.dataset.fingerprint(), "subset_sha256": hashlib.sha256(index).hexdigest()[:16]}

    def frame_table(self) -> tuple[np.ndarray, np.ndarray]:
        episodes, frames = self.dataset.frame_table()
        idx = np.asarray(self.indices, dtype=np.int64)
        return episodes[idx], frames[idx]
