"""Contact-pose estimation (x, y, θ) from one tactile frame: a small CNN and the PCA baseline (the paper's Table 2).

The CNN sees the residual at half the render size plus two coordinate channels (a pose is a position) and
regresses (x / half-pad-width, y / half-pad-height, cos 2θ, sin 2θ): poses are drawn with θ in [0, π), so 2θ
codes them without a wrap. The PCA baseline takes the contact mask's centroid as (x, y) and its principal axis
as θ, with each object's constant angle offset fitted on the training frames (circular mean); it is told the
object, the CNN is not.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from controltac_il.tactile.pose import pose_to_pixel


def _inputs(residuals: np.ndarray) -> torch.Tensor:
    """uint8 (N, H, W, 3) -> float (N, 5, H/2, W/2): residual about 0 plus x, y coordinate channels."""
    x = torch.from_numpy(residuals).permute(0, 3, 1, 2).float().sub(127.0).div(128.0)
    x = F.avg_pool2d(x, 2)
    n, _, h, w = x.shape
    gy, gx = torch.meshgrid(torch.linspace(-1, 1, h), torch.linspace(-1, 1, w), indexing="ij")
    return torch.cat([x, gx.expand(n, 1, h, w), gy.expand(n, 1, h, w)], 1)


class PoseNet(nn.Module):
    """(N, 5, h, w) -> (N, 4) [x, y normalised; cos 2θ, sin 2θ]."""

    def __init__(self, hw: tuple[int, int]):
        super().__init__()
        ch = (5, 16, 32, 48, 64)
        self.convs = nn.Sequential(*(m for a, b in zip(ch, ch[1:]) for m in (nn.Conv2d(a, b, 3, 2, 1), nn.ReLU())))
        h, w = hw
        for _ in range(4):
            h, w = (h + 1) // 2, (w + 1) // 2
        self.head = nn.Sequential(nn.Flatten(), nn.Linear(64 * h * w, 128), nn.ReLU(), nn.Linear(128, 4))

    def forward(self, x):
        return self.head(self.convs(x))


def encode_poses(poses: np.ndarray, half_pad_mm: tuple[float, float]) -> np.ndarray:
    """(N, 3) (x_mm, y_mm, θ) -> (N, 4) regression targets."""
    hh, hw = half_pad_mm
    return np.stack([poses[:, 0] / hw, poses[:, 1] / hh, np.cos(2 * poses[:, 2]), np.sin(2 * poses[:, 2])], 1)


def decode_poses(y: np.ndarray, half_pad_mm: tuple[float, float]) -> np.ndarray:
    hh, hw = half_pad_mm
    return np.stack([y[:, 0] * hw, y[:, 1] * hh, np.mod(np.arctan2(y[:, 3], y[:, 2]) / 2, np.pi)], 1)


def fit_cnn(residuals: np.ndarray, poses: np.ndarray, half_pad_mm: tuple[float, float], steps: int, seed: int,
            batch: int = 32, lr: float = 2e-3) -> PoseNet:
    """Train a PoseNet on (residuals uint8 (N, H, W, 3), poses (N, 3)) for ``steps`` Adam steps."""
    torch.manual_seed(seed)
    x = _inputs(residuals)
    y = torch.from_numpy(encode_poses(poses, half_pad_mm)).float()
    net = PoseNet(x.shape[-2:])
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    g = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        idx = torch.randint(0, len(x), (min(batch, len(x)),), generator=g)
        loss = F.mse_loss(net(x[idx]), y[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    return net.eval()


@torch.no_grad()
def predict_cnn(net: PoseNet, residuals: np.ndarray, half_pad_mm: tuple[float, float]) -> np.ndarray:
    return decode_poses(net(_inputs(residuals)).numpy(), half_pad_mm)


def _axis(mask: np.ndarray) -> tuple[float, float, float]:
    """(column, row, θ) of a mask: centroid and principal-axis angle (counter-clockwise as displayed, [0, π));
    fewer than 3 contact pixels: the image centre and 0."""
    rows, cols = np.nonzero(mask)
    if len(rows) < 3:
        return (mask.shape[1] - 1) / 2, (mask.shape[0] - 1) / 2, 0.0
    c, r = cols.mean(), rows.mean()
    cov = np.cov(np.stack([cols - c, -(rows - r)]))  # y up
    evals, evecs = np.linalg.eigh(cov)
    v = evecs[:, -1]
    return float(c), float(r), float(np.mod(np.arctan2(v[1], v[0]), np.pi))


def fit_pca(masks: np.ndarray, poses: np.ndarray, objects: list[str]) -> dict[str, float]:
    """Each object's angle offset θ - principal axis (circular mean over its training frames, mod π)."""
    out = {}
    for name in sorted(set(objects)):
        d = [2 * (p[2] - _axis(m)[2]) for m, p, o in zip(masks, poses, objects) if o == name]
        out[name] = float(np.mod(np.arctan2(np.mean(np.sin(d)), np.mean(np.cos(d))) / 2, np.pi))
    return out


def predict_pca(masks: np.ndarray, objects: list[str], offsets: dict[str, float], mm_per_px: float) -> np.ndarray:
    """(N, 3) poses from the masks' centroids and axes (+ each object's offset)."""
    h, w = masks.shape[1:3]
    x0, y0 = pose_to_pixel(0.0, 0.0, mm_per_px, (h, w))
    out = []
    for m, o in zip(masks, objects):
        c, r, a = _axis(m)
        out.append(((c - x0) * mm_per_px, -(r - y0) * mm_per_px, np.mod(a + offsets.get(o, 0.0), np.pi)))
    return np.asarray(out)


def pose_errors(pred: np.ndarray, true: np.ndarray) -> dict:
    """Mean position error (mm, Euclidean) and angle error (degrees, modulo π) with their SDs."""
    pos = np.hypot(pred[:, 0] - true[:, 0], pred[:, 1] - true[:, 1])
    d = np.mod(pred[:, 2] - true[:, 2], np.pi)
    ang = np.degrees(np.minimum(d, np.pi - d))
    return {"xy_mm": float(pos.mean()), "xy_mm_sd": float(pos.std()), "theta_deg": float(ang.mean()),
            "theta_deg_sd": float(ang.std()), "n": int(len(pos))}
