"""An in-memory dataset with LeRobot's item conventions, for ForceAugment's LeRobot tests without LeRobot.

``LeRobotLike`` returns items as ``LeRobotDataset.__getitem__`` does: ``episode_index``, ``frame_index``,
``index``, ``timestamp`` (0-d tensors), ``task_index``, ``task`` (str), ``observation.state``, ``action``,
cameras ``observation.images.<name>`` as float32 (C, H, W) in [0, 1], the tactile stream among them; with
``delta_timestamps`` (s) and ``fps`` a key holds a window (T, ...) of the frames at frame + round(delta x fps),
clamped to the episode, with ``<key>_is_pad`` (T,) bool marking the clamped positions. No force labels and
no backgrounds unless asked for.
"""

import numpy as np
import torch
from torch.utils.data import Dataset

from aug_fixtures import synthetic_episode

GEL = "observation.images.gelsight"
FORCE = "observation.gelsight_force"
BG = "observation.gelsight_background"
FPS = 10


class LeRobotLike(Dataset):
    """LeRobot-convention items of synthetic episodes. episodes: {episode_index: Episode}; first: frame_index
    of each episode's first frame; rows: item order (default: episode after episode, frames in order)."""

    def __init__(self, episodes, *, uint8_hwc=False, labels=False, backgrounds=False, delta_timestamps=None,
                 fps=FPS, first=None, rows=None, columns=False):
        self.eps, self.first = episodes, first or {}
        self.uint8_hwc, self.labels, self.backgrounds = uint8_hwc, labels, backgrounds
        self.windows = delta_timestamps
        self.delta_timestamps, self.fps, self.rate = delta_timestamps, fps, fps  # fps: what LeRobot shows
        table = [(e, self.first.get(e, 0) + t) for e in episodes for t in range(len(episodes[e].qpos))]
        self.rows = [table[i] for i in rows] if rows is not None else table
        if columns:  # LeRobot's hf_dataset: the index columns without decoding any image
            self.hf_dataset = {"episode_index": [e for e, _ in self.rows], "frame_index": [t for _, t in self.rows]}

    def __len__(self):
        return len(self.rows)

    def image(self, array):
        t = torch.from_numpy(np.ascontiguousarray(array))
        return t if self.uint8_hwc else t.permute(2, 0, 1).float() / 255

    def frame(self, e, t):
        ep, i = self.eps[e], t - self.first.get(e, 0)
        out = {GEL: self.image(ep.tactile["left"][i]), "observation.images.wrist": self.image(ep.images["wrist"][i]),
               "observation.state": torch.from_numpy(ep.qpos[i]), "action": torch.from_numpy(ep.action[i])}
        if self.labels:
            out[FORCE] = torch.from_numpy(ep.force["left"][i])
        return out

    def __getitem__(self, idx):
        e, t = self.rows[idx]
        item = {"episode_index": torch.tensor(e), "frame_index": torch.tensor(t), "index": torch.tensor(idx),
                "timestamp": torch.tensor(t / self.rate, dtype=torch.float32), "task_index": torch.tensor(0),
                "task": "insert the peg", **self.frame(e, t)}
        if self.backgrounds:
            item[BG] = self.image(self.eps[e].tactile_background["left"])
        lo, hi = self.first.get(e, 0), self.first.get(e, 0) + len(self.eps[e].qpos) - 1
        for key, deltas in (self.windows or {}).items():
            want = [t + round(d * self.rate) for d in deltas]
            item[key] = torch.stack([self.frame(e, min(max(f, lo), hi))[key] for f in want])
            item[f"{key}_is_pad"] = torch.tensor([not lo <= f <= hi for f in want])
        return item


def episodes(labels=True):
    return {0: synthetic_episode(9, 0, range(3, 8), labels=labels),
            1: synthetic_episode(7, 1, range(1, 6), labels=labels)}
