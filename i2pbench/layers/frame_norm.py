"""Per-keypoint MLPs normalised over each frame's keypoints: what the paper's 1x1 convolutions with BatchNorm do,
with the statistics of one frame (padding masked) rather than of a batch.

BatchNorm centres every channel over all the pixels (or points) of the batch, which removes what a channel holds
equally for every keypoint of a frame. That matters here: the [local | global] layout hands every keypoint its
frame's global feature, 3-8 times the norm of the local part, and a per-keypoint norm (LayerNorm, used before)
keeps that shared part, so every descriptor of a frame pointed the same way (cosine 0.99 between two pixels and
0.9998 between two points of an untrained CPU-size model) and the circle loss only learnt to make the two
modalities' shared directions orthogonal: its plateau near 3.9. Per-frame statistics keep frames independent (a
batch is the mean of its frames) and are the same in training and at inference (no running averages from batches
of one or two); they do depend on the frame's set of keypoints, which the method's extractors fix.
"""

from __future__ import annotations

import torch
from torch import nn

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)


class FrameNorm(nn.Module):
    """each channel of x [... x M x C] standardised over the frame's M keypoints (mask [... x M]: the real ones),
    then scaled and shifted per channel."""

    def __init__(self, channels: int, eps: float = 1e-5) -> None:
        super().__init__()
        self.eps = eps
        self.weight, self.bias = nn.Parameter(torch.ones(channels)), nn.Parameter(torch.zeros(channels))

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        w = torch.ones_like(x[..., :1]) if mask is None else mask[..., None].to(x.dtype)
        count = w.sum(-2, keepdim=True).clamp(min=1)  # a frame with no keypoint has nothing to normalise
        mean = (x * w).sum(-2, keepdim=True) / count
        var = ((x - mean).square() * w).sum(-2, keepdim=True) / count
        return (x - mean) * torch.rsqrt(var + self.eps) * self.weight + self.bias


class FrameMLP(nn.Module):
    """Linear + FrameNorm + ReLU per hidden width, then a last Linear: x [... x M x C_in] -> [... x M x C_out]."""

    def __init__(self, widths: tuple[int, ...]) -> None:
        super().__init__()
        pairs = list(zip(widths[:-1], widths[1:], strict=True))
        self.linears = nn.ModuleList(nn.Linear(cin, cout) for cin, cout in pairs)
        self.norms = nn.ModuleList(FrameNorm(cout) for _, cout in pairs[:-1])

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        for linear, norm in zip(self.linears, self.norms, strict=False):
            x = torch.relu(norm(linear(x), mask))
        return self.linears[-1](x)
