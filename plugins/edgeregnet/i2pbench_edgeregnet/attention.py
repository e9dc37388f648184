"""Attention-based feature exchange: positional encodings, then blocks of self- and cross-attention (SuperGlue style).

Each block updates both sets with self-attention, then exchanges messages 2D <-> 3D with cross-attention computed from
the same inputs for both directions (as SuperGlue and LightGlue). An update is x + MLP([x, message]) (LightGlue's).
2D and 3D get their own weights by default (the modalities differ); `share_weights` ties them as SuperGlue does.
Positions: pixels are centred and divided by half the image's longer side; 3D edge points are centred on their
centroid and divided by their largest distance to it (translation-invariant, as the PointNet++ encoder's input), and
optionally turned into their yaw-canonical frame (i2pbench/layers/canonical.py).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import BatchedStage, Component, Device, Exchanger, Frame, Keypoints2D, Keypoints3D, width_mismatch
from i2pbench.layers.attention import key_mask
from i2pbench.layers.pointnet2 import normalize_points
from i2pbench.layers.positions import centred_pixels

PIXEL_SPAN = 0.5  # the image's longer side spans [-1, 1]


def relu_mlp(widths: tuple[int, ...]) -> nn.Sequential:
    """Linear + ReLU layers, the last one linear with a zero bias."""
    layers: list[nn.Module] = []
    for cin, cout in zip(widths[:-1], widths[1:], strict=True):
        layers += [nn.Linear(cin, cout), nn.ReLU(inplace=True)]
    layers.pop()
    nn.init.zeros_(layers[-1].bias)
    return nn.Sequential(*layers)


class AttentionalUpdate(nn.Module):
    """x + MLP([x, MultiHeadAttention(x, source)])."""

    def __init__(self, dim: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.q, self.kv, self.out = nn.Linear(dim, dim), nn.Linear(dim, 2 * dim), nn.Linear(dim, dim)
        self.ffn = nn.Sequential(nn.Linear(2 * dim, 2 * dim), nn.LayerNorm(2 * dim), nn.GELU(), nn.Linear(2 * dim, dim))

    def forward(self, x: torch.Tensor, source: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """x [B x N x D], source [B x M x D], mask: SDPA's [B x 1 x 1 x M] over source or None -> [B x N x D]."""
        q = self.q(x).unflatten(-1, (self.heads, -1)).transpose(1, 2)  # [B x H x N x D/H]
        k, v = self.kv(source).unflatten(-1, (2, self.heads, -1)).permute(2, 0, 3, 1, 4)  # 2 x [B x H x M x D/H]
        message = F.scaled_dot_product_attention(q, k, v, attn_mask=mask).transpose(1, 2).flatten(2)
        return x + self.ffn(torch.cat([x, self.out(message)], -1))


class ExchangeBlock(nn.Module):
    """self-attention on each set, then cross-attention both ways."""

    def __init__(self, dim: int, heads: int, share_weights: bool) -> None:
        super().__init__()
        self.self2d, self.cross2d = AttentionalUpdate(dim, heads), AttentionalUpdate(dim, heads)
        self.self3d = self.self2d if share_weights else AttentionalUpdate(dim, heads)
        self.cross3d = self.cross2d if share_weights else AttentionalUpdate(dim, heads)

    def forward(
        self, d2: torch.Tensor, d3: torch.Tensor, mask2d: torch.Tensor | None, mask3d: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """d2 [B x M2 x D], d3 [B x M3 x D], SDPA key masks (see `key_mask`) -> same shapes."""
        d2, d3 = self.self2d(d2, d2, mask2d), self.self3d(d3, d3, mask3d)
        return self.cross2d(d2, d3, mask3d), self.cross3d(d3, d2, mask2d)


class AttentionExchanger(BatchedStage, Exchanger):
    """Positional encodings added to both descriptor sets, then `num_blocks` self + cross attention blocks."""

    name = "attention"
    default_conf: dict[str, Any] = {
        "descriptor_dim": 256,  # D, must equal the encoders'
        "num_blocks": 6,  # stacked self + cross attention blocks
        "num_heads": 4,
        "pe_mlp": (32, 64, 128),  # hidden widths of the positional encoders (2D: u, v; 3D: x, y, z) before D
        "share_weights": False,  # True: one set of attention weights for both modalities (SuperGlue)
        "canonical_yaw": False,  # True: 3D positions in their yaw-canonical frame (layers/canonical.py; our addition)
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        dim, hidden = self.conf["descriptor_dim"], tuple(self.conf["pe_mlp"])
        self.pe2d, self.pe3d = relu_mlp((2, *hidden, dim)), relu_mlp((3, *hidden, dim))
        share = self.conf["share_weights"]
        self.blocks = nn.ModuleList(
            ExchangeBlock(dim, self.conf["num_heads"], share) for _ in range(self.conf["num_blocks"])
        )

    def check_compatible(self, upstream: Mapping[str, Component]) -> str | None:
        return width_mismatch(self, upstream, ("descriptor_dim",))

    def compile_targets(self) -> list[nn.Module]:
        """the attention blocks: dense matmuls, SDPA and MLPs on [B x M x D], shapes fixed by the keypoint caps."""
        return list(self.blocks)

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, device: Device = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's positions: normalised pixels [M2 x 2] and normalised (canonical) edge points [M3 x 3]."""
        uv = torch.from_numpy(np.asarray(kp2d.uv, np.float32)).to(device)
        xyz = torch.from_numpy(np.asarray(kp3d.xyz, np.float32)).to(device)
        if len(xyz):
            xyz = normalize_points(xyz, xyz, self.conf["canonical_yaw"])
        return {"uv": centred_pixels(uv, frame.image_size, PIXEL_SPAN), "xyz": xyz}

    def forward(
        self,
        inputs: dict[str, torch.Tensor],
        d2: torch.Tensor,
        d3: torch.Tensor,
        mask2d: torch.Tensor | None = None,
        mask3d: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """`prepare`d positions (uv [B x M2 x 2], xyz [B x M3 x 3]), d2 [B x M2 x D], d3 [B x M3 x D], keypoint
        masks [B x M2], [B x M3] (None: no padding) -> updated d2, d3."""
        d2 = d2.float() + self.pe2d(inputs["uv"])
        d3 = d3.float() + self.pe3d(inputs["xyz"])
        m2, m3 = key_mask(mask2d), key_mask(mask3d)
        for block in self.blocks:
            d2, d3 = block(d2, d3, m2, m3)
        return d2, d3
