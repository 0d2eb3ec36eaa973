"""ACT HDF5 episodes, extended with tactile images, tactile backgrounds and force labels.

File layout (ACT's, plus the tactile groups; T frames, one file per episode)::

    /action                                  float32 (T, A)
    /observations/qpos                       float32 (T, D)
    /observations/qvel                       float32 (T, D)        only when recorded
    /observations/images/<camera>            uint8   (T, H, W, 3)  RGB
    /observations/tactile/<sensor>           uint8   (T, H, W, 3)  RGB tactile image
    /observations/tactile_background/<sensor> uint8  (H, W, 3)     no-contact frame, when known
    /observations/force/<sensor>             float32 (T, 3)        [Fx, Fy, Fz] N, sensor frame, when known
    attrs: sim (bool), plus any user attributes

A folder of episodes holds ``episode_0.hdf5``, ``episode_1.hdf5``, ... (ACT's naming).
Files are written atomically (temp file + rename) and always opened read-only for reading.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from controltac_il.datasets.checks import (ACTION, NEEDS, OBSERVATIONS, QPOS, check_finite, check_force_labels,
                                          open_episode)
from controltac_il.io import atomic_path

EPISODE_PATTERN = re.compile(r"^episode_(\d+)\.hdf5$")
COMPRESSIONS = (None, "gzip", "lzf")  # h5py's filters that every install carries


def _as_float32(name: str, value, ndim: int) -> np.ndarray:
    arr = np.asarray(value)
    if arr.ndim != ndim or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name}: expected a numeric array with {ndim} dims, got dtype {arr.dtype} shape {arr.shape}")
    return np.ascontiguousarray(arr, dtype=np.float32)


def _as_image_stack(name: str, value, ndim: int) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype != np.uint8 or arr.ndim != ndim or arr.shape[-1] != 3:
        want = "(T, H, W, 3)" if ndim == 4 else "(H, W, 3)"
        raise ValueError(f"{name}: expected uint8 {want} RGB, got dtype {arr.dtype} shape {arr.shape}")
    return np.ascontiguousarray(arr)


@dataclass
class Episode:
    """One demonstration, T frames, in memory.

    Fields:
        qpos: float32 (T, D) proprioception (joint or end-effector state + gripper).
        action: float32 (T, A) commanded action at each frame.
        images: camera name -> uint8 (T, H, W, 3) RGB frames.
        tactile: sensor name -> uint8 (T, H, W, 3) RGB tactile images.
        tactile_background: sensor name -> uint8 (H, W, 3) no-contact frame; a sensor may be missing
            (then readers estimate one from the episode's no-contact frames).
        force: sensor name -> float32 (T, 3) [Fx, Fy, Fz] in N, sensor frame, Fz > 0 pressing; may be empty.
        sim: True for simulated demonstrations (ACT's ``sim`` attribute).
        attrs: extra file attributes (str, numbers or small arrays), e.g. task name, control rate.
        qvel: optional float32 (T, D) velocities (ACT records them; unused by training).
    """

    qpos: np.ndarray
    action: np.ndarray
    images: dict[str, np.ndarray]
    tactile: dict[str, np.ndarray] = field(default_factory=dict)
    tactile_background: dict[str, np.ndarray] = field(default_factory=dict)
    force: dict[str, np.ndarray] = field(default_factory=dict)
    sim: bool = False
    attrs: dict = field(default_factory=dict)
    qvel: np.ndarray | None = None

    def __post_init__(self):
        self.qpos = _as_float32("qpos", self.qpos, 2)
        self.action = _as_float32("action", self.action, 2)
        T = self.qpos.shape[0]
        if T < 1:
            raise ValueError("qpos: an episode needs at least one frame (T >= 1)")
        if self.action.shape[0] != T:
            raise ValueError(f"action: expected {T} frames like qpos, got shape {self.action.shape}")
        if self.qvel is not None:
            self.qvel = _as_float32("qvel", self.qvel, 2)
            if self.qvel.shape[0] != T:
                raise ValueError(f"qvel: expected {T} frames like qpos, got shape {self.qvel.shape}")
        for group in ("images", "tactile", "tactile_background", "force"):
            value = getattr(self, group)
            if not isinstance(value, dict):
                raise ValueError(f"{group}: expected a dict name -> array, got {type(value).__name__}")
            for name in value:
                if not isinstance(name, str) or not name or "/" in name:
                    raise ValueError(f"{group}: names must be non-empty strings without '/', got {name!r}")
        self.images = {k: _as_image_stack(f"images/{k}", v, 4) for k, v in self.images.items()}
        self.tactile = {k: _as_image_stack(f"tactile/{k}", v, 4) for k, v in self.tactile.items()}
        self.tactile_background = {
            k: _as_image_stack(f"tactile_background/{k}", v, 3) for k, v in self.tactile_background.items()
        }
        self.force = {k: _as_float32(f"force/{k}", v, 2) for k, v in self.force.items()}
        for group in ("images", "tactile", "force"):
            for name, arr in getattr(self, group).items():
                if arr.shape[0] != T:
                    raise ValueError(f"{group}/{name}: expected {T} frames like qpos, got shape {arr.shape}")
        for name, arr in self.force.items():
            if arr.shape[1] != 3:
                raise ValueError(f"force/{name}: expected (T, 3) [Fx, Fy, Fz], got shape {arr.shape}")
        for name, bg in self.tactile_background.items():
            if name not in self.tactile:
                raise ValueError(f"tactile_background/{name}: no tactile stream of that name")
            if bg.shape != self.tactile[name].shape[1:]:
                raise ValueError(
                    f"tactile_background/{name}: expected shape {self.tactile[name].shape[1:]} like its "
                    f"tactile frames, got {bg.shape}"
                )
        if not isinstance(self.sim, (bool, np.bool_)):  # bool("false") is True
            raise ValueError(f"sim: expected True or False, got {self.sim!r}")
        self.sim = bool(self.sim)
        if not isinstance(self.attrs, dict):
            raise ValueError(f"attrs: expected a dict, got {type(self.attrs).__name__}")
        if "sim" in self.attrs:
            raise ValueError("attrs: 'sim' is reserved; use Episode.sim")

    def __len__(self) -> int:
        return int(self.qpos.shape[0])


def write_episode(path: str | os.PathLike, episode: Episode, compression: str | None = None,
                  overwrite: bool = False) -> Path:
    """Write ``episode`` to ``path`` in the extended ACT layout, atomically; returns the path.

    Images are chunked one frame per chunk (fast random frame reads); ``compression`` (None, "gzip" or "lzf":
    COMPRESSIONS) applies to image datasets only, default none (fastest reads). An existing ``path`` is refused
    (ValueError) unless ``overwrite``, as is anything a reader would refuse (NaN, force labels in mN or pulling).
    """
    if not isinstance(episode, Episode):
        raise ValueError(f"episode: expected an Episode, got {type(episode).__name__}")
    path = Path(path)
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise ValueError(f"path: {path} already exists; write_episode replaces a file only with overwrite=True")
    if compression not in COMPRESSIONS:
        raise ValueError(f"compression: expected one of {COMPRESSIONS}, got {compression!r}")
    numbers = {"qpos": episode.qpos, "action": episode.action, "qvel": episode.qvel}
    for name, values in numbers.items():  # what every reader would refuse: never written
        if values is not None:
            check_finite(name, values)
    for name, values in episode.force.items():
        check_force_labels(f"force/{name}", values)
    with atomic_path(path, suffix=".hdf5") as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["sim"] = episode.sim
            for key, value in episode.attrs.items():
                try:
                    f.attrs[key] = value
                except (TypeError, ValueError) as exc:
                    raise ValueError(f"attrs/{key}: value of type {type(value).__name__} cannot be stored in HDF5") from exc
            f.create_dataset("action", data=episode.action)
            obs = f.create_group(OBSERVATIONS)
            obs.create_dataset("qpos", data=episode.qpos)
            if episode.qvel is not None:
                obs.create_dataset("qvel", data=episode.qvel)
            for group in ("images", "tactile"):
                g = obs.create_group(group)
                for name, arr in getattr(episode, group).items():
                    g.create_dataset(name, data=arr, chunks=(1, *arr.shape[1:]), compression=compression)
            g = obs.create_group("tactile_background")
            for name, arr in episode.tactile_background.items():
                g.create_dataset(name, data=arr)
            g = obs.create_group("force")
            for name, arr in episode.force.items():
                g.create_dataset(name, data=arr)
    return path


def _group_arrays(obs: h5py.Group, name: str) -> dict[str, np.ndarray]:
    if name not in obs:
        return {}
    return {k: obs[name][k][()] for k in obs[name].keys()}


def read_episode(path: str | os.PathLike) -> Episode:
    """Read a whole episode into memory (file opened read-only)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"episode file not found: {path}")
    with open_episode(path) as f:
        if ACTION not in f or QPOS not in f:
            raise ValueError(f"{path}: not an ACT episode ({NEEDS})")
        obs = f[OBSERVATIONS]
        attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items() if k != "sim"}
        return Episode(
            qpos=obs["qpos"][()],
            action=f["action"][()],
            images=_group_arrays(obs, "images"),
            tactile=_group_arrays(obs, "tactile"),
            tactile_background=_group_arrays(obs, "tactile_background"),
            force=_group_arrays(obs, "force"),
            sim=bool(f.attrs.get("sim", False)),
            attrs=attrs,
            qvel=obs["qvel"][()] if "qvel" in obs else None,
        )


def episode_paths(root: str | os.PathLike) -> list[Path]:
    """``episode_<i>.hdf5`` files in ``root``, sorted by index ``i`` (ACT naming)."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"episode folder not found: {root}")
    found = []
    for p in root.iterdir():
        m = EPISODE_PATTERN.match(p.name)
        if m and p.is_file():
            found.append((int(m.group(1)), p))
    return [p for _, p in sorted(found)]


def episode_index(path: str | os.PathLike) -> int:
    """The integer ``i`` of ``episode_<i>.hdf5``."""
    m = EPISODE_PATTERN.match(Path(path).name)
    if not m:
        raise ValueError(f"episode path: expected a name like episode_<i>.hdf5, got {Path(path).name!r}")
    return int(m.group(1))
