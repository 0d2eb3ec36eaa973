"""Serves a LeRobot v3.0 folder as ACT's training data: ``EpisodeDataset``'s items and attributes, so that
``train_act.py --dataset ROOT`` (and ForceAugment on the training split) take it directly.

Per item, from the folder's (``LeRobotFolder``, without LeRobot)::

    observation.state                  -> observation.qpos          float32 (D,)
    action window [0, chunk_size) / fps -> action (chunk_size, A), action_is_pad (chunk_size,) bool (the
                                          episode's last action repeated past its end)
    camera observation.images.<c>      -> observation.images.<c>    uint8 (3, H, W)
    tactile camera (``tactile_keys``)  -> observation.tactile.<s>   uint8 (3, H, W), s = the camera's last name
                                          part, with observation.tactile_background.<s> (``background_images``'
                                          image, else estimated per episode from its no-contact frames) and, where
                                          the folder has its label (``force_keys``), observation.force.<s>
                                          float32 (3,) N

Default tactile keys: the cameras whose name holds "gelsight", "tactile" or "digit"; default force key of
``observation.images.<s>``: ``observation.<s>.force`` where the folder has it. ``stats`` (qpos and action
mean / std, std floored at ``STD_FLOOR``) come from the data's columns, no image decoded.
``recorded_episode`` says which recorded episode each episode is, or is a ForceAugment copy of (a folder the
augment command wrote: originals first, then copy k of the n recorded episodes' episode e at k n + e), so that a
split by episode keeps an episode and its copies on one side.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import torch
from torch.utils.data import Dataset
from tqdm import tqdm

from controltac_il.config import is_int
from controltac_il.datasets.act_dataset import STD_FLOOR
from controltac_il.datasets.background import estimate_background, given_backgrounds, image_digests
from controltac_il.datasets.checks import check_force_labels
from controltac_il.lerobot.provenance import COPY
from controltac_il.lerobot.reader import LeRobotFolder, decode_png, numbers, read_info
from controltac_il.streams import (HDF5, LEROBOT, LEROBOT_STATE, background_key, force_key, lerobot_name,
                                   lerobot_to_hdf5, tactile_key)

TACTILE_WORDS = ("gelsight", "tactile", "digit")


def _numeric(root: Path, keys: list[str]) -> dict[str, np.ndarray]:
    """{key: the column of every data file, in row order, as float64 (N, D)}, all columns read in one pass;
    ValueError naming the key, episode and frame of the first row that is not finite."""
    files = sorted((root / "data").glob("*/*.parquet"))
    tables = [pq.read_table(p, columns=[*keys, "episode_index", "frame_index"]) for p in files]
    out = {}
    for key in keys:
        values = np.concatenate([numbers(t.column(key)).astype(np.float64) for t in tables])
        bad = ~np.isfinite(values.reshape(len(values), -1)).all(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            where = pa.concat_tables([t.select(["episode_index", "frame_index"]) for t in tables])
            e, f = (int(where.column(c)[i].as_py()) for c in ("episode_index", "frame_index"))
            raise ValueError(f"{root.name}: {key} holds NaN or inf (first at episode {e}, frame {f}); "
                             "it must be finite")
        out[key] = values
    return out


def tactile_cameras(features: dict) -> list[str]:
    """The camera features (``info.json``'s) whose names hold one of TACTILE_WORDS: a folder's tactile streams
    unless named otherwise (``train_act.py`` and the augment command alike)."""
    return [k for k, ft in features.items() if ft["dtype"] in ("image", "video") and any(w in k for w in TACTILE_WORDS)]


def default_force_keys(tactile: list[str], features: dict) -> dict[str, str]:
    """{tactile camera key: its force label ``observation.<camera>.force``} where the folder has that feature."""
    found = {k: force_key(lerobot_name(k), LEROBOT) for k in tactile}
    return {k: f for k, f in found.items() if f in features}


class LeRobotEpisodes(Dataset):
    """Frames of a LeRobot v3.0 folder as ``EpisodeDataset`` items (module docstring).

    Args:
        root: the folder (never written to).
        chunk_size: actions per item (ACT's N_a), >= 1.
        tactile_keys: camera keys that are tactile streams, or their names (``gs_left`` for
            ``observation.images.gs_left``); default: the cameras whose names hold TACTILE_WORDS, with a warning
            where none does (the policy would see no touch).
        force_keys: {tactile key: force feature} (default: ``observation.<s>.force`` where present).
        tactile_sensors: tactile names to return (None = all; () = none: a vision-only policy).
        background_images: {tactile key or name: path of an RGB image file of that sensor at rest, no contact}:
            its background in every episode (default: estimated per episode from the episode's frames).
    """

    def __init__(self, root, chunk_size: int = 20, tactile_keys=None, force_keys=None, tactile_sensors=None,
                 background_images=None):
        if not is_int(chunk_size) or chunk_size < 1:
            raise ValueError(f"chunk_size: expected an int >= 1, got {chunk_size!r}")
        tactile_keys, tactile_sensors = ([x] if isinstance(x, str) else x for x in (tactile_keys, tactile_sensors))
        self.root, self.chunk_size = Path(root).resolve(), int(chunk_size)
        info = read_info(self.root)
        features, fps = info["features"], int(info["fps"])
        for key in (LEROBOT_STATE, "action"):
            if key not in features:
                raise ValueError(f"root: {self.root} has no {key!r} feature (ACT needs the state and the actions)")
        cams = [k for k, ft in features.items() if ft["dtype"] in ("image", "video")]
        if tactile_keys is None:
            every = tactile_cameras(features)
            if not every and tactile_sensors != ():
                warnings.warn(f"{self.root.name}: no camera's name holds {' / '.join(TACTILE_WORDS)}, so none is "
                              f"taken as a tactile sensor (cameras: {cams}); name them with --tactile-keys "
                              "(tactile_keys)", stacklevel=2)
        else:
            every = [tactile_key(k, LEROBOT) if k not in cams and tactile_key(k, LEROBOT) in cams else k
                     for k in tactile_keys]
        unknown = [k for k in every if k not in cams]
        if unknown:
            raise ValueError(f"tactile_keys: {unknown} are not cameras of the dataset ({cams})")
        named = {lerobot_name(k) for k in every}
        if tactile_sensors is not None and set(tactile_sensors) - named:
            raise ValueError(f"tactile_sensors: {sorted(set(tactile_sensors) - named)} are not tactile cameras of the "
                             f"dataset ({sorted(named)})")
        tactile = [k for k in every if tactile_sensors is None or lerobot_name(k) in set(tactile_sensors)]
        self.tactile_keys = {lerobot_name(k): k for k in tactile}
        self.camera_keys = {lerobot_name(k): k for k in cams if k not in every}
        self.force_keys = self._forces(tactile, force_keys, features)
        self.folder = LeRobotFolder(self.root, delta_timestamps={"action": [k / fps for k in range(chunk_size)]})
        self.cameras, self.tactile_sensors = list(self.camera_keys), list(self.tactile_keys)
        self.force_sensors = [s for s in self.tactile_sensors if s in self.force_keys]
        self.episode_ids = sorted(self.folder.episodes)
        self._position = {e: n for n, e in enumerate(self.episode_ids)}
        self.lengths = np.asarray([int(self.folder.episodes[e]["length"]) for e in self.episode_ids], np.int64)
        copies = [COPY] if COPY in features else []
        columns = _numeric(self.root, list(dict.fromkeys([LEROBOT_STATE, "action", *self.force_keys.values(), *copies])))
        self.recorded_episode = self._recorded(columns.get(COPY))
        self.stats = {name: {"mean": v.mean(0).astype(np.float32), "std": np.maximum(v.std(0), STD_FLOOR).astype(np.float32)}
                      for name, v in (("qpos", columns[LEROBOT_STATE]), ("action", columns["action"]))}
        for key in self.force_keys.values():  # finite, in N, Fz > 0 pressing, as an HDF5 episode's labels
            check_force_labels(f"{self.root.name}: {key}", columns[key])
        given = given_backgrounds(background_images,
                                  {s: (k, tactile_key(s, HDF5)) for s, k in self.tactile_keys.items()},
                                  {s: tuple(features[k]["shape"][:2]) for s, k in self.tactile_keys.items()})
        self.backgrounds = self._backgrounds(given)
        self._given = image_digests(given)

    def _recorded(self, copy: np.ndarray | None) -> dict[int, int]:
        """{episode: the recorded episode it is or copies}, from the ``augment.copy`` column (N, 1) in row order
        (None: a folder ForceAugment did not write, every episode recorded); ValueError where that column does not
        follow the augment command's layout."""
        ids = self.episode_ids
        if copy is None:
            return {e: e for e in ids}
        episodes, _ = self.frame_table()
        first = {int(e): int(copy[i, 0]) for i, e in reversed(list(enumerate(episodes)))}
        n = sum(first[e] == 0 for e in ids)
        if n == 0 or len(ids) % n or any(first[e] != pos // n for pos, e in enumerate(ids)):
            raise ValueError(f"root: {self.root.name}'s {COPY} column does not follow the augment command's layout "
                             "(its recorded episodes first, then each copy of them in turn), so no episode can be "
                             "told from its copies")
        return {e: ids[pos % n] for pos, e in enumerate(ids)}

    @staticmethod
    def _forces(tactile: list[str], force_keys, features: dict) -> dict[str, str]:
        if force_keys is None:
            found = {lerobot_name(k): f for k, f in default_force_keys(tactile, features).items()}
            odd = [f"{f} {features[f]['shape']}" for f in found.values() if tuple(features[f]["shape"]) != (3,)]
            if odd:
                raise ValueError(f"force_keys: {odd} are not (3,) [Fx, Fy, Fz] N features; pass force_keys= naming "
                                 "the right ones")
            return found
        if not isinstance(force_keys, dict):
            raise ValueError(f"force_keys: expected {{tactile key: force key}}, got {type(force_keys).__name__}")
        bad = [f for k, f in force_keys.items() if k not in tactile or f not in features or
               tuple(features[f]["shape"]) != (3,)]
        if bad:
            raise ValueError(f"force_keys: {bad} are not (3,) force features of tactile keys of the dataset")
        return {lerobot_name(k): f for k, f in force_keys.items()}

    def _backgrounds(self, given: dict) -> dict:
        """{(episode position, sensor): uint8 (H, W, 3)}: ``given``'s image, else estimated from the episode's own
        frames."""
        out = {(n, s): given[s] for n in range(len(self.episode_ids)) for s in given}
        estimated = {s: k for s, k in self.tactile_keys.items() if s not in given}
        if estimated:
            warnings.warn(f"{self.root.name}: LeRobot folders record no tactile background; estimated per episode "
                          f"from its no-contact frames for {sorted(estimated)} (background_images: a recorded one)",
                          stacklevel=3)
        for n, e in enumerate(tqdm(self.episode_ids, desc="tactile backgrounds", file=sys.stderr,
                                   disable=True if not estimated else None)):
            table = self.folder.episode_table(e) if estimated else None
            for s, key in estimated.items():
                frames = (self.folder.video_frames(key, e) if self.folder.features[key]["dtype"] == "video"
                          else _pngs(table.column(key), key, self.folder.data_file(e), e))
                force = numbers(table.column(self.force_keys[s])).astype(np.float32) if s in self.force_keys else None
                out[(n, s)] = estimate_background(frames, force)[0]
        return out

    def fingerprint(self) -> dict:
        """The folder's identity, and the given background images' pixels' digests (they change the items)."""
        return {"root": str(self.root), **self.folder.fingerprint(),
                **({"background_images": self._given} if self._given else {})}

    def __len__(self) -> int:
        return len(self.folder)

    def frame_table(self) -> tuple[np.ndarray, np.ndarray]:
        return self.folder.frame_table()

    def __getitem__(self, index: int) -> dict:
        """Item ``index`` in EpisodeDataset's layout."""
        src = self.folder[index]
        e = int(src["episode_index"])
        item = {"episode_index": e, "frame_index": int(src["frame_index"]),
                lerobot_to_hdf5(LEROBOT_STATE): src[LEROBOT_STATE].float()}
        for key in self.camera_keys.values():
            item[lerobot_to_hdf5(key)] = _uint8(src[key])
        for s, key in self.tactile_keys.items():
            item[lerobot_to_hdf5(key, tactile=True)] = _uint8(src[key])
            bg = self.backgrounds[(self._position[e], s)]
            item[background_key(s, HDF5)] = torch.from_numpy(bg).permute(2, 0, 1)
        for s in self.force_sensors:
            item[force_key(s, HDF5)] = src[self.force_keys[s]].float()
        item["action"], item["action_is_pad"] = src["action"].float(), src["action_is_pad"]
        return item


def _uint8(image: torch.Tensor) -> torch.Tensor:
    """float (3, H, W) in [0, 1] (x / 255 of uint8) -> the uint8 it came from."""
    return (image * 255).round().to(torch.uint8)


def _pngs(column, key: str, path: Path, episode: int) -> np.ndarray:
    """RGB uint8 (L, H, W, 3) of an episode's PNG column ``key``; a frame that is no readable PNG is refused in
    one ValueError line naming the data parquet ``path``, the episode and the frame."""
    return np.stack([decode_png(b, key, f"{path} (episode {episode}, frame {i})")
                     for i, b in enumerate(column.combine_chunks().field("bytes").to_pylist())])
