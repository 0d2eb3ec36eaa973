"""Compact CNN: residual image (B, 3, h, w), normalised -> normalised force (B, 3)."""

from __future__ import annotations

import torch
from torch import nn

from controltac_il.estimators.config import EstimatorConfig


def _conv(cin: int, cout: int, stride: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


class ForceCNN(nn.Module):
    """Stride-2 conv stages (``config.widths``), then mean- and max-pooled features into a two-layer head.

    Global pooling keeps the reading independent of where the contact sits on the pad; the max
    pool keeps small, sharp contacts from being averaged away.
    """

    def __init__(self, config: EstimatorConfig):
        super().__init__()
        layers, cin = [], 3
        for w in config.widths:
            layers += [_conv(cin, w, 2), _conv(w, w, 1)]
            cin = w
        self.features = nn.Sequential(*layers)
        self.head = nn.Sequential(
            nn.Linear(2 * cin, config.hidden),
            nn.ReLU(inplace=True),
            nn.Linear(config.hidden, 3),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.features(x)
        pooled = torch.cat([f.mean(dim=(2, 3)), f.amax(dim=(2, 3))], dim=1)
        return self.head(pooled)
