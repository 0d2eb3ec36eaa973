"""Small synthetic ACT data for the ACT tests: items in the EpisodeDataset layout.

The action chunk is a known function of the observation (the qpos plus a term read from the
third-view image brightness), so a few hundred training steps must lower the loss.
"""

from __future__ import annotations

import torch
from torch.utils.data import Dataset

from policies.act import ACTConfig

CAMERAS = ("third_view", "wrist")
SENSORS = ("left", "right")


def tiny_config(**overrides) -> ACTConfig:
    base = dict(camera_names=CAMERAS, tactile_names=SENSORS, state_dim=5, action_dim=5, chunk_size=6,
                camera_size=(24, 32), tactile_size=(24, 32), dim_model=32, n_heads=2, dim_feedforward=64,
                n_encoder_layers=1, n_vae_encoder_layers=1, latent_dim=4, dropout=0.0, lr=1e-3, lr_backbone=1e-3)
    base.update(overrides)
    return ACTConfig.from_preset("cpu", **base)


class SyntheticACTDataset(Dataset):
    """``n`` items; images (3, 24, 32), qpos (5,), action (chunk, 5) with a padded tail on some items."""

    def __init__(self, n: int = 32, chunk: int = 6, seed: int = 0) -> None:
        g = torch.Generator().manual_seed(seed)
        self.qpos = torch.randn(n, 5, generator=g)
        self.level = torch.rand(n, generator=g)
        self.tactile = torch.randint(0, 256, (n, 3, 24, 32), generator=g, dtype=torch.uint8)
        self.background = torch.full((3, 24, 32), 120, dtype=torch.uint8)
        steps = torch.arange(chunk, dtype=torch.float32)[:, None] / chunk
        self.action = self.qpos[:, None, :] + steps[None] * (2 * self.level[:, None, None] - 1)
        self.pad = torch.zeros(n, chunk, dtype=torch.bool)
        self.pad[::3, chunk - 2:] = True

    def __len__(self) -> int:
        return len(self.qpos)

    def __getitem__(self, i: int) -> dict:
        img = torch.full((3, 24, 32), int(255 * self.level[i]), dtype=torch.uint8)
        item = {"episode_index": i // 8, "frame_index": i % 8, "observation.qpos": self.qpos[i],
                "action": self.action[i], "action_is_pad": self.pad[i]}
        for c in CAMERAS:
            item[f"observation.images.{c}"] = img
        for s in SENSORS:
            item[f"observation.tactile.{s}"] = self.tactile[i]
            item[f"observation.tactile_background.{s}"] = self.background
        return item

    def stats(self) -> dict:
        a = self.action.reshape(-1, 5)
        return {"qpos": {"mean": self.qpos.mean(0).tolist(), "std": self.qpos.std(0).tolist()},
                "action": {"mean": a.mean(0).tolist(), "std": a.std(0).tolist()}}
