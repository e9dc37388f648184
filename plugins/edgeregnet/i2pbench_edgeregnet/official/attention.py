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
channel = d * heads + head); the checkpoint importer (importer.py) permutes their weights once.
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
from i2pbench.layers.pointnet2 import seeded_cloud
from i2pbench.layers.positions import centred_pixels

from .pointnet2 import OfficialPointNet2, normalize
from .superpoint import OfficialSuperPoint

LAYERS = ("self", "cross") * 6  # cali_glue.py:202
SUPERGLUE_SPAN = 0.7  # pixels divided by 0.7 of the canvas's longer side (cali_glue.py:27-37)


class ChannelNorm(nn.BatchNorm1d):
    """BatchNorm1d over the last dim of a channels-last [B x N x C] tensor (the authors' norm on [B x C x N])."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.training:  # one pass over the channels-last tensor, no transposed copies
            scale, shift = norm_affine(self)
            return torch.addcmul(shift, x, scale)
        return super().forward(x.transpose(1, 2)).transpose(1, 2)


def norm_affine(norm: nn.BatchNorm1d) -> tuple[torch.Tensor, torch.Tensor]:
    """an eval-mode BatchNorm as y = x * scale + shift."""
    scale = norm.weight * torch.rsqrt(norm.running_var + norm.eps)
    return scale, norm.bias - norm.running_mean * scale


def batchnorm_mlp(widths: tuple[int, ...]) -> nn.Sequential:
    """SuperGlue's MLP, channels-last: Linear + BatchNorm + ReLU, the last Linear alone with a zero bias."""
    layers: list[nn.Module] = []
    for cin, cout in zip(widths[:-1], widths[1:], strict=True):
        layers += [nn.Linear(cin, cout), ChannelNorm(cout), nn.ReLU()]
    del layers[-2:]
    nn.init.zeros_(layers[-1].bias)
    return nn.Sequential(*layers)


def run_mlp(layers: nn.Sequential, x: torch.Tensor, groups: int = 1) -> torch.Tensor:
    """`batchnorm_mlp`'s layers on x [G*B x N x C], G modalities stacked on the batch axis. In eval each Linear +
    BatchNorm is one Linear with the norm folded in; in training each modality is normalised by its own batch
    statistics, as the authors' separate calls are."""
    modules = list(layers)
    folded = False  # the previous Linear took this norm in
    for layer, following in zip(modules, [*modules[1:], None], strict=True):
        if folded:
            folded = False
        elif isinstance(layer, nn.Linear) and isinstance(following, ChannelNorm) and not following.training:
            scale, shift = norm_affine(following)
            x, folded = F.linear(x, layer.weight * scale[:, None], layer.bias * scale + shift), True
        elif isinstance(layer, ChannelNorm) and groups > 1:
            x = torch.cat([layer(part) for part in x.chunk(groups)])
        else:
            x = layer(x)
    return x


class AttentionalPropagation(nn.Module):
    """one tied GNN layer: x + MLP([x, MultiHeadAttention(x, source)]) for the 3D and the 2D side alike."""

    def __init__(self, dim: int, heads: int) -> None:
        super().__init__()
        self.heads = heads
        self.q, self.k, self.v, self.merge = (nn.Linear(dim, dim) for _ in range(4))
        self.mlp = batchnorm_mlp((2 * dim, 2 * dim, dim))

    def forward(
        self, d3: torch.Tensor, d2: torch.Tensor, cross: bool, m3: torch.Tensor | None, m2: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """d3 [B x M3 x D], d2 [B x M2 x D], each attending to the other (cross) or to itself, SDPA key masks or
        None -> the updates of d3 and d2. Sides of one size run as one batch: each tied weight in one product."""
        if d3.shape != d2.shape:
            s3, s2, k3, k2 = (d2, d3, m2, m3) if cross else (d3, d2, m3, m2)
            return self.update(d3, s3, k3), self.update(d2, s2, k2)
        x = torch.cat([d3, d2])
        source = x.roll(len(d3), 0) if cross else x  # cross: the other side, batch for batch
        k3, k2 = (m2, m3) if cross else (m3, m2)
        mask = None if k3 is None and k2 is None else torch.cat([full_mask(k3, d3), full_mask(k2, d2)])
        return self.update(x, source, mask, groups=2).chunk(2)

    def update(self, x: torch.Tensor, source: torch.Tensor, mask: torch.Tensor | None, groups: int = 1) -> torch.Tensor:
        """x [B x N x D], source [B x M x D], SDPA mask over source or None -> MLP([x, message]) [B x N x D]."""
        q, k, v = (t.unflatten(-1, (self.heads, -1)).transpose(1, 2) for t in self.project(x, source))
        message = F.scaled_dot_product_attention(q, k, v, attn_mask=mask).transpose(1, 2).flatten(2)
        first, norm, _, last = self.mlp
        if norm.training:
            return run_mlp(self.mlp, torch.cat([x, self.merge(message)], -1), groups)
        # eval: merge, the first Linear and its norm as one linear map of [x, message]: 14% fewer FLOPs in the MLP
        scale, shift = norm_affine(norm)
        weight, bias = first.weight * scale[:, None], first.bias * scale + shift
        own, merged = weight.split(x.shape[-1], 1)
        weight, bias = torch.cat([own, merged @ self.merge.weight], 1), torch.addmv(bias, merged, self.merge.bias)
        return F.linear(F.linear(torch.cat([x, message], -1), weight, bias).relu_(), last.weight, last.bias)

    def project(self, x: torch.Tensor, source: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """q(x), k(source), v(source) [B x N x D], in one product where source is x and one for k and v else."""
        if source is x:
            return stacked(x, self.q, self.k, self.v).chunk(3, -1)
        return self.q(x), *stacked(source, self.k, self.v).chunk(2, -1)


def stacked(x: torch.Tensor, *layers: nn.Linear) -> torch.Tensor:
    """the Linear layers' outputs on x side by side, from one product."""
    return F.linear(x, torch.cat([layer.weight for layer in layers]), torch.cat([layer.bias for layer in layers]))


def full_mask(mask: torch.Tensor | None, side: torch.Tensor) -> torch.Tensor:
    """a side's SDPA key mask [B x 1 x 1 x M], all keys where it has none."""
    if mask is None:
        return torch.ones(len(side), 1, 1, side.shape[1], dtype=torch.bool, device=side.device)
    return mask


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
        self.kenc2d, self.kenc3d = batchnorm_mlp((2, *hidden, dim)), batchnorm_mlp((3, *hidden, dim))
        self.layers = nn.ModuleList(AttentionalPropagation(dim, self.conf["num_heads"]) for _ in self.conf["layers"])

    def check_compatible(self, upstream: Mapping[str, Component]) -> str | None:
        return width_mismatch(self, upstream, ("descriptor_dim",))

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, device: Device = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's positions: normalised pixels [M2 x 2], edge points normalised by the cloud [M3 x 3]."""
        uv = torch.from_numpy(np.asarray(kp2d.uv, np.float32))
        xyz = torch.from_numpy(np.asarray(kp3d.xyz, np.float32))
        if len(xyz):
            xyz = normalize(xyz, torch.from_numpy(seeded_cloud(frame, self.conf["num_points"])))
        uv = centred_pixels(uv, tuple(self.conf["canvas"]), SUPERGLUE_SPAN)
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
        e2, e3 = run_mlp(self.kenc2d, inputs["uv"]), run_mlp(self.kenc3d, inputs["xyz"])
        if trace is not None:
            trace.update(enc2d=e2, enc3d=e3)
        d2, d3 = d2.float() + e2, d3.float() + e3
        m2, m3 = key_mask(mask2d), key_mask(mask3d)
        for layer, kind in zip(self.layers, self.conf["layers"], strict=True):
            delta3, delta2 = layer(d3, d2, kind == "cross", m3, m2)
            d3, d2 = d3 + delta3, d2 + delta2
        return d2, d3
