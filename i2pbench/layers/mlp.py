"""Per-keypoint MLPs with LayerNorm (DeepI2P's fusion and classifier; CorrI2P's stages normalise over the frame's
keypoints instead, frame_norm.py)."""

from __future__ import annotations

from torch import nn

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)


def linear_mlp(widths: tuple[int, ...]) -> nn.Sequential:
    """Linear + LayerNorm + ReLU per hidden width (no activation after the last Linear)."""
    layers: list[nn.Module] = []
    for cin, cout in zip(widths[:-2], widths[1:-1], strict=True):
        layers += [nn.Linear(cin, cout), nn.LayerNorm(cout), nn.ReLU(inplace=True)]
    return nn.Sequential(*layers, nn.Linear(widths[-2], widths[-1]))
