"""The authors' two-way exchange (network.py `CorrI2P.forward` between the encoders and the heads).

Image side: at strides 32 and 16, a 1x1 stack on [image map, point cloud's global feature] gives each pixel a
softmax over the node_b (stride 32) or node_a (stride 16) nodes, whose features it averages and concatenates with
its own; the decoder upsamples stride 32 to 16 to 8 to 4 (with stride 2's map, nearest-halved, beside stride 4).
Point side: a 1x1 stack on [node feature, image global feature] gives each node a softmax over the stride-32 (node_b)
or stride-16 (node_a) pixels whose features it averages; node_b's MLP, then node_a's (with node_b's interpolated at
node_a); every point takes node_a's and node_b's features interpolated from its 3 nearest (weights 1 - d / sum d,
as theirs: they sum to 2) beside its own two PointNet features, through the per-point MLP.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .image import UpSample
from .mlp import PointMLP, conv_bn_relu_1x1
from .points import gather_columns, nearest


def interpolate(index: torch.Tensor, at: torch.Tensor, nodes: torch.Tensor, feats: torch.Tensor) -> torch.Tensor:
    """feats [B x C x M] of nodes [B x 3 x M] at points at [B x 3 x N] from their index [B x N x k] nearest nodes,
    weighted 1 - d / sum(d) (network.py `upsample_by_interpolation`) -> [B x C x N]."""
    dist = torch.norm(at[..., None] - gather_columns(nodes, index), dim=1)
    weight = 1 - dist / dist.sum(2, keepdim=True)
    return (weight[:, None] * gather_columns(feats, index)).sum(3)


def spread(weights: torch.Tensor, feats: torch.Tensor) -> torch.Tensor:
    """sum over nodes j of weights [B x J x H x W] times feats [B x C x J] -> [B x C x H x W]."""
    return torch.einsum("bjhw,bcj->bchw", weights, feats)


class Exchange(nn.Module):
    """the encoders' outputs -> the image decoder's stride-4 map and the per-point features."""

    def __init__(
        self, nodes_a: int = 128, nodes_b: int = 128, cells32: int = 80, k_interp: int = 3, ca: int = 64,
        cb: int = 256, cg: int = 512,
    ) -> None:  # fmt: skip
        super().__init__()
        self.k_interp = k_interp
        self.image_attention32 = conv_bn_relu_1x1((512 + cg, 512, 512, nodes_b), 2)
        self.image_attention16 = conv_bn_relu_1x1((256 + cg, 256, 256, nodes_a), 2)
        self.up16 = UpSample(512 + cb + 256 + ca, 256)
        self.up8 = UpSample(256 + 128, 128)
        self.up4 = UpSample(128 + 64 + 64, 64)
        self.node_b_attention = PointMLP(cb + 512, (256, cells32), act_last=False)
        self.node_b_mlp = PointMLP(cb + cg + 512 + 512, (1024, 512, 512), act_last=False)
        self.node_a_attention = PointMLP(ca + 512, (256, 4 * cells32), act_last=False)
        self.node_a_mlp = PointMLP(ca + 256 + 512, (512, 128, 128), act_last=False)
        self.per_point = PointMLP(128 + 512 + ca // 2 + ca, (256, 256, 128))

    def image(self, maps: list[torch.Tensor], points: dict[str, torch.Tensor], trace: dict) -> torch.Tensor:
        """ResNet maps and the point encoder's outputs -> the decoded stride-4 map [B x 64 x H/4 x W/4]."""
        s2, s4, s8, s16, s32 = maps[:5]
        glob = points["global"][..., None]
        logits32 = self.image_attention32(torch.cat([s32, glob.expand(-1, -1, *s32.shape[2:])], 1))
        logits16 = self.image_attention16(torch.cat([s16, glob.expand(-1, -1, *s16.shape[2:])], 1))
        fused32 = torch.cat([spread(logits32.softmax(1), points["node_b"]), s32], 1)
        fused16 = torch.cat([spread(logits16.softmax(1), points["node_a"]), s16], 1)
        trace.update(image_attention32_logits=logits32, image_attention16_logits=logits16)
        trace["up16"] = self.up16(fused32, fused16)
        trace["up8"] = self.up8(trace["up16"], s8)
        trace["img_s2_half"] = F.interpolate(s2, scale_factor=0.5)  # nearest: every other row and column
        trace["up4"] = self.up4(trace["up8"], torch.cat([s4, trace["img_s2_half"]], 1))
        return trace["up4"]

    def points(
        self, maps: list[torch.Tensor], points: dict[str, torch.Tensor], pc: torch.Tensor, node_a: torch.Tensor,
        node_b: torch.Tensor, trace: dict,
    ) -> torch.Tensor:  # fmt: skip
        """ResNet maps, the point encoder's outputs, the cloud and nodes -> per-point features [B x 128 x N]."""
        s16, s32, pooled = maps[3].flatten(2), maps[4].flatten(2), maps[5][..., 0]
        img_b, img_a = pooled.expand(-1, -1, node_b.shape[2]), pooled.expand(-1, -1, node_a.shape[2])
        logits_b = self.node_b_attention(torch.cat([points["node_b"], img_b], 1))
        seen_b = torch.einsum("bcp,bpm->bcm", s32, logits_b.softmax(1))
        glob = points["global"].expand(-1, -1, node_b.shape[2])
        up_b = self.node_b_mlp(torch.cat([points["node_b"], glob, seen_b, img_b], 1))
        logits_a = self.node_a_attention(torch.cat([points["node_a"], img_a], 1))
        seen_a = torch.einsum("bcp,bpm->bcm", s16, logits_a.softmax(1))
        b_at_a = interpolate(nearest(node_a, node_b, self.k_interp), node_a, node_b, up_b)
        up_a = self.node_a_mlp(torch.cat([points["node_a"], b_at_a, seen_a], 1))
        b_at_pc = interpolate(nearest(pc, node_b, self.k_interp), pc, node_b, up_b)
        a_at_pc = interpolate(points["point_node_a"], pc, node_a, up_a)
        trace.update(node_b_attention_logits=logits_b, node_b_up=up_b, node_a_attention_logits=logits_a, node_a_up=up_a)
        per_point = self.per_point(torch.cat([a_at_pc, b_at_pc, points["first"], points["second"]], 1))
        trace["per_point"] = per_point
        return per_point
