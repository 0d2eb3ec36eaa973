"""Image backbones written in this repo (no torchvision): ResNet-18 and a small strided CNN.

Both map a float image batch (B, 3, H, W) to a feature map (B, C, h, w); ``out_channels`` and
``stride`` describe it. Trained from scratch (no pretrained weights ship with the project).
"""

from __future__ import annotations

import math

import torch
from torch import nn


class BasicBlock(nn.Module):
    """Two 3x3 convs with batch norm and an identity (or 1x1 projection) shortcut."""

    def __init__(self, cin: int, cout: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.shortcut = nn.Identity()
        if stride != 1 or cin != cout:
            self.shortcut = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = torch.relu(self.bn1(self.conv1(x)))
        y = self.bn2(self.conv2(y))
        return torch.relu(y + self.shortcut(x))


class ResNet18(nn.Module):
    """ResNet-18 trunk (He et al. 2016): 7x7 stem, max pool, 4 stages of 2 basic blocks.

    (B, 3, H, W) -> (B, 512, ceil(H/32), ceil(W/32)); the classification head is left out.
    """

    out_channels = 512
    stride = 32

    def __init__(self) -> None:
        super().__init__()
        self.stem = nn.Sequential(
            nn.Conv2d(3, 64, 7, 2, 3, bias=False), nn.BatchNorm2d(64), nn.ReLU(inplace=True),
            nn.MaxPool2d(3, 2, 1),
        )
        stages, cin = [], 64
        for cout, stride in ((64, 1), (128, 2), (256, 2), (512, 2)):
            stages.append(nn.Sequential(BasicBlock(cin, cout, stride), BasicBlock(cout, cout, 1)))
            cin = cout
        self.stages = nn.Sequential(*stages)
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.stages(self.stem(x))


class SmallCNN(nn.Module):
    """Four 3x3 stride-2 convs (32, 64, 96, 128 channels) with group norm: stride 16, ~0.2 M params."""

    out_channels = 128
    stride = 16

    def __init__(self) -> None:
        super().__init__()
        layers, cin = [], 3
        for cout in (32, 64, 96, 128):
            layers += [nn.Conv2d(cin, cout, 3, 2, 1, bias=False), nn.GroupNorm(8, cout), nn.ReLU(inplace=True)]
            cin = cout
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


def build_backbone(name: str) -> nn.Module:
    """Backbone by config name ("resnet18" or "small_cnn")."""
    if name == "resnet18":
        return ResNet18()
    if name == "small_cnn":
        return SmallCNN()
    raise ValueError(f"backbone must be 'resnet18' or 'small_cnn', got {name!r}")


def sine_positions_2d(dim: int, h: int, w: int, device=None) -> torch.Tensor:
    """Fixed 2-D sinusoidal position code (h*w, dim): half the channels encode rows, half columns."""
    quarter = dim // 4
    freqs = torch.exp(-math.log(10000.0) * torch.arange(quarter, device=device, dtype=torch.float32) / quarter)
    ys = torch.arange(h, device=device, dtype=torch.float32)[:, None] * freqs  # (h, q)
    xs = torch.arange(w, device=device, dtype=torch.float32)[:, None] * freqs  # (w, q)
    row = torch.cat([ys.sin(), ys.cos()], dim=1)[:, None, :].expand(h, w, 2 * quarter)
    col = torch.cat([xs.sin(), xs.cos()], dim=1)[None, :, :].expand(h, w, 2 * quarter)
    return torch.cat([row, col], dim=2).reshape(h * w, 4 * quarter)


def sine_positions_1d(dim: int, n: int, device=None) -> torch.Tensor:
    """Fixed 1-D sinusoidal position code (n, dim)."""
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, device=device, dtype=torch.float32) / half)
    angles = torch.arange(n, device=device, dtype=torch.float32)[:, None] * freqs
    return torch.cat([angles.sin(), angles.cos()], dim=1)
