"""The authors' feature exchange (ESRSchao/EdgeRegNet, models/cali_glue.py:14-116, 200-224): positional encoders
added to the descriptors, then SuperGlue's attentional GNN, ['self', 'cross'] * 6.

As their code, and unlike attention.py:
- ONE set of weights per layer, applied to the 3D and to the 2D descriptors alike (cali_glue.py:103-115);
- x + MLP([x, message]) with MLP [2D, 2D, D], BatchNorm1d and ReLU, a zero last bias at initialisation;
- 4 heads, scores divided by sqrt(D / heads), no mask in their code (a padded batch masks here);
- both updates of a layer read the descriptors from before it;
- pixels normalised as SuperGlue's (centre of the canvas, divided by 0.7 of its longer side, cali_glue.py:27-37);
  edge points enter with the normalised xyz the 3D branch sees.
One thing differs in form only: the projections are channels-last Linear layers whose heads are contiguous channel
blocks (channel = head * D/heads + d). The authors' Conv1d projections interleave them (`view(B, D/heads, heads, N)`:
channel = d * heads + head); the checkpoint importer (official_import.py) permutes their weights once.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import BatchedStage, Component, Device, Exchanger, Frame, Keypoints2D, Keypoints3D
from i2pbench.layers.attention import key_mask
from i2pbench.layers.pointnet2 import seeded_cloud

from .matching import descriptor_dim_mismatch
from .official_pointnet2 import OfficialPointNet2, normalize
from .official_superpoint import OfficialSuperPoint

LAYERS = ("self", "cross") * 6  # cali_glue.py:202


class ChannelNorm(nn.BatchNorm1d):
    """BatchNorm1d over the last dim of a channels-last [B x N x C] tensor (the authors' norm on [B x C x N])."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(x.transpose(1, 2)).transpose(1, 2)


def mlp(widths: tuple[int, ...]) -> nn.Sequential:
    """SuperGlue's MLP, channels-last: Linear + BatchNorm + ReLU, the last Linear alone with a zero bias."""
    layers: list[nn.Module] = []
    for cin, cout in zip(widths[:-1], widths[1:], strict=True):
        layers += [nn.Linear(cin, cout), ChannelNorm(cout), nn.ReLU()]
    del layers[-2:]
    nn.init.zeros_(layers[-1].bias)
    return nn.Sequential(*layers)


def normalize_pixels(uv: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """pixels [... x 2] on a canvas of size (W, H) -> centred and divided by 0.7 of its longer side."""
    w, h = size
    return (uv - uv.new_tensor([w / 2, h / 2])) / (max(w, h) * 0.7)


class AttentionalPropagation(nn.Module):
    """one GNN layer: x + MLP([x, MultiHeadAttention(x, source)])."""

    def __init__(self, dim: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.q, self.k, self.v, self.merge = (nn.Linear(dim, dim) for _ in range(4))
        self.mlp = mlp((2 * dim, 2 * dim, dim))

    def forward(self, x: torch.Tensor, source: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """x [B x N x D], source [B x M x D], SDPA mask over source or None -> the update [B x N x D]."""
        q, k, v = (p(t).unflatten(-1, (self.heads, -1)).transpose(1, 2) for p, t in zip(
            (self.q, self.k, self.v), (x, source, source), strict=True))  # fmt: skip
        message = F.scaled_dot_product_attention(q, k, v, attn_mask=mask).transpose(1, 2).flatten(2)
        return self.mlp(torch.cat([x, self.merge(message)], -1))


class OfficialAttention(BatchedStage, Exchanger):
    """The authors' positional encoders and tied attentional GNN (module docstring)."""

    name = "attention-official"
    default_conf: dict[str, Any] = {
        "descriptor_dim": 256,  # D, must equal the encoders'
        "num_heads": 4,  # cali_glue.py:104
        "layers": LAYERS,  # attention kinds in order, one tied layer each
        "kenc": (32, 64, 128, 256),  # hidden widths of kenc2d / kenc3d before D (cali_glue.py:200-201)
        "canvas": OfficialSuperPoint.default_conf["canvas"],  # (W, H) the pixels are normalised by
        "num_points": OfficialPointNet2.default_conf["num_points"],  # the cloud whose centroid and extent normalise xyz
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        dim, hidden = self.conf["descriptor_dim"], tuple(self.conf["kenc"])
        self.kenc2d, self.kenc3d = mlp((2, *hidden, dim)), mlp((3, *hidden, dim))
        self.layers = nn.ModuleList(AttentionalPropagation(dim, self.conf["num_heads"]) for _ in self.conf["layers"])

    def check_compatible(self, upstream: Mapping[str, Component]) -> str | None:
        return descriptor_dim_mismatch(self, upstream)

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, device: Device = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's positions: normalised pixels [M2 x 2], edge points normalised by the cloud [M3 x 3]."""
        uv = torch.from_numpy(np.asarray(kp2d.uv, np.float32))
        xyz = torch.from_numpy(np.asarray(kp3d.xyz, np.float32))
        if len(xyz):
            xyz = normalize(xyz, torch.from_numpy(seeded_cloud(frame, self.conf["num_points"])))
        uv = normalize_pixels(uv, tuple(self.conf["canvas"]))
        return {"uv": uv.to(device), "xyz": xyz.to(device)}

    def forward(
        self,
        inputs: dict[str, torch.Tensor],
        d2: torch.Tensor,
        d3: torch.Tensor,
        mask2d: torch.Tensor | None = None,
        mask3d: torch.Tensor | None = None,
        trace: dict | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """positions (uv [B x M2 x 2], xyz [B x M3 x 3]), d2 [B x M2 x D], d3 [B x M3 x D], masks [B x M] or None
        -> updated d2, d3; `trace`, when given, receives the positional encodings."""
        e2, e3 = self.kenc2d(inputs["uv"]), self.kenc3d(inputs["xyz"])
        if trace is not None:
            trace.update(enc2d=e2, enc3d=e3)
        d2, d3 = d2.float() + e2, d3.float() + e3
        m2, m3 = key_mask(mask2d), key_mask(mask3d)
        for layer, kind in zip(self.layers, self.conf["layers"], strict=True):
            s3, s2, k3, k2 = (d3, d2, m3, m2) if kind == "self" else (d2, d3, m2, m3)
            # two calls, as the authors': in training each modality's batch statistics are its own
            d3, d2 = d3 + layer(d3, s3, k3), d2 + layer(d2, s2, k2)
        return d2, d3
