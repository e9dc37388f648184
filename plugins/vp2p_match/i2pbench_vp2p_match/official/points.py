"""VP2P-Match's point branch (`PointsEncoder_pointwise`, `is_pc_norm=False`): PointNet++ set abstraction with point
transformer layers, in metres.

Two set abstractions (1,024 centres with 64 neighbours in 20 m, then 256 with 32 in 40 m: the paper's 0.2 / 0.4
radii times 100, as the point clouds are not normalised), each followed by a point transformer (vector attention over
16 nearest neighbours with a learned position encoding), a global abstraction over all 256 (the cloud's 512-d global
feature), then feature propagation back up (inverse-distance weights over the 3 nearest), each level added to a
1x1 projection of its down-path features and passed through a transformer, down to every input point (128-d).
Grouping uses i2pbench.layers.pointnet2 (farthest point sampling from index 0, the first neighbours in index order,
3-NN); module names are the authors' (`sa_module_1.mlp_conv.0.conv.weight`, `transformer_end_2.pos_mlp.1.running_var`,
...).
"""

from __future__ import annotations

import torch
from torch import nn

from i2pbench.layers.pointnet2 import ball_query, farthest_point_sampling, gather, three_nn


class ConvNorm(nn.Module):
    """a 1x1 convolution (1-D or 2-D), BatchNorm and ReLU, under the authors' names `conv` and `bn`."""

    def __init__(self, c_in: int, c_out: int, dims: int = 1) -> None:
        super().__init__()
        self.conv = (nn.Conv1d if dims == 1 else nn.Conv2d)(c_in, c_out, 1)
        self.bn = (nn.BatchNorm1d if dims == 1 else nn.BatchNorm2d)(c_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.relu(self.bn(self.conv(x)))


def mlp(c_in: int, widths: list[int], dims: int) -> nn.Sequential:
    layers, last = [], c_in
    for width in widths:
        layers.append(ConvNorm(last, width, dims))
        last = width
    return nn.Sequential(*layers)


def grouped(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """values [B x C x N] at index [B x M x K] -> [B x C x M x K] (pointnet2's grouping_operation)."""
    return gather(values.transpose(1, 2), index).permute(0, 3, 1, 2)


class SetAbstraction(nn.Module):
    """`npoint` farthest centres, `nsample` neighbours within `radius` (relative xyz beside their features), a shared
    MLP and a max over each ball; `npoint` None: one ball of every point around the origin."""

    def __init__(self, npoint: int | None, nsample: int | None, radius: float | None, c_in: int, widths: list[int]):
        super().__init__()
        self.npoint, self.nsample, self.radius = npoint, nsample, radius
        self.mlp_conv = mlp(c_in + 3, widths, dims=2)

    def forward(self, xyz: torch.Tensor, feats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if self.npoint is None:
            centres = xyz.new_zeros(len(xyz), 3, 1)
            groups = torch.cat([xyz, feats], 1).unsqueeze(2)
        else:
            points = xyz.transpose(1, 2).contiguous()
            chosen = farthest_point_sampling(points, self.npoint).to(xyz.device)
            centres = gather(points, chosen).transpose(1, 2)
            balls = ball_query(points, centres.transpose(1, 2).contiguous(), self.radius, self.nsample)
            balls = balls.to(xyz.device)
            groups = torch.cat([grouped(xyz, balls) - centres.unsqueeze(3), grouped(feats, balls)], 1)
        return centres, self.mlp_conv(groups).max(dim=3).values


class FeaturePropagation(nn.Module):
    """features of the coarse level read at the fine points (inverse distances of the 3 nearest), beside the fine
    level's own features, through a shared MLP."""

    def __init__(self, c_coarse: int, widths: list[int], c_fine: int) -> None:
        super().__init__()
        self.mlp_conv = mlp(c_coarse + c_fine, widths, dims=1)

    def forward(self, fine_xyz, coarse_xyz, fine_feats, coarse_feats) -> torch.Tensor:
        fine, coarse = fine_xyz.transpose(1, 2).contiguous(), coarse_xyz.transpose(1, 2).contiguous()
        nearest = three_nn(fine, coarse).to(fine.device)
        dist = (fine.unsqueeze(2) - gather(coarse, nearest)).square().sum(-1).sqrt().clamp_min(1e-10)
        weight = 1.0 / dist
        weight = weight / weight.sum(-1, keepdim=True)
        read = (grouped(coarse_feats, nearest) * weight.unsqueeze(1)).sum(-1)
        return self.mlp_conv(torch.cat([read, fine_feats], 1))


def nearest_neighbours(pos: torch.Tensor, k: int) -> torch.Tensor:
    """[B x 3 x N] -> [B x N x k]: each point's k nearest (itself first), by the authors' expanded squared distance."""
    p = pos.transpose(1, 2)
    dist = -2 * torch.matmul(p, p.transpose(1, 2))
    dist = dist + p.square().sum(-1).unsqueeze(2) + p.square().sum(-1).unsqueeze(1)
    return torch.argsort(dist, dim=-1)[:, :, :k]


class PointTransformer(nn.Module):
    """vector attention over each point's `n_knn` nearest neighbours, residual around it."""

    def __init__(self, c_in: int, dim: int = 64, n_knn: int = 16, pos_hidden: int = 64, expand: int = 4) -> None:
        super().__init__()
        self.n_knn = n_knn
        self.conv_key, self.conv_query, self.conv_value = (nn.Conv1d(dim, dim, 1) for _ in range(3))
        self.pos_mlp = nn.Sequential(
            nn.Conv2d(3, pos_hidden, 1), nn.BatchNorm2d(pos_hidden), nn.ReLU(), nn.Conv2d(pos_hidden, dim, 1)
        )
        self.attn_mlp = nn.Sequential(
            nn.Conv2d(dim, dim * expand, 1), nn.BatchNorm2d(dim * expand), nn.ReLU(), nn.Conv2d(dim * expand, dim, 1)
        )
        self.linear_start, self.linear_end = nn.Conv1d(c_in, dim, 1), nn.Conv1d(dim, c_in, 1)

    def forward(self, x: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
        h = self.linear_start(x)
        knn = nearest_neighbours(pos, self.n_knn)
        pos_embedding = self.pos_mlp(pos.unsqueeze(3) - grouped(pos, knn))
        attention = self.attn_mlp(self.conv_query(h).unsqueeze(3) - grouped(self.conv_key(h), knn) + pos_embedding)
        value = self.conv_value(h).unsqueeze(3) + pos_embedding
        return self.linear_end((attention.softmax(-1) * value).sum(-1)) + x


class PointsEncoder(nn.Module):
    """[B x 7 x N] (x, y, z in metres, intensity, normal) -> global [B x 512], per point [B x 128 x N]."""

    def __init__(self) -> None:
        super().__init__()
        self.sa_module_1 = SetAbstraction(1024, 64, 20.0, 7, [64, 64, 128])
        self.transformer_start_1 = PointTransformer(128)
        self.sa_module_2 = SetAbstraction(256, 32, 40.0, 128, [128, 128, 256])
        self.transformer_start_2 = PointTransformer(256)
        self.sa_module_3 = SetAbstraction(None, None, None, 256, [256, 512, 512])
        self.fp_module_3 = FeaturePropagation(512, [256, 256], 256)
        self.transformer_end_2 = PointTransformer(256)
        self.fp_module_2 = FeaturePropagation(256, [256, 128], 128)
        self.transformer_end_1 = PointTransformer(128)
        self.fp_module_1 = FeaturePropagation(128, [128, 128, 128], 6)
        self.conv_DownFeatureStep1 = ConvNorm(128, 128)  # noqa: N815 (the authors' key)
        self.conv_DownFeatureStep2 = ConvNorm(256, 256)  # noqa: N815

    def forward(self, cloud: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        trace = self.trace(cloud)
        return trace["global"], trace["pointwise"]

    def trace(self, cloud: torch.Tensor) -> dict[str, torch.Tensor]:
        """the levels' centres and features down (`l1_xyz`, `l1_down`, ...) and up (`l2_up`, `l1_up`), the global
        feature and the per-point output."""
        l0_xyz = cloud[:, :3].contiguous()
        l1_xyz, l1_down = self.sa_module_1(l0_xyz, cloud)
        l1_down = self.transformer_start_1(l1_down, l1_xyz)
        l2_xyz, l2_down = self.sa_module_2(l1_xyz, l1_down)
        l2_down = self.transformer_start_2(l2_down, l2_xyz)
        l3_xyz, l3 = self.sa_module_3(l2_xyz, l2_down)
        l2_up = self.fp_module_3(l2_xyz, l3_xyz, l2_down, l3) + self.conv_DownFeatureStep2(l2_down)
        l2_up = self.transformer_end_2(l2_up, l2_xyz)
        l1_up = self.fp_module_2(l1_xyz, l2_xyz, l1_down, l2_up) + self.conv_DownFeatureStep1(l1_down)
        l1_up = self.transformer_end_1(l1_up, l1_xyz)
        pointwise = self.fp_module_1(l0_xyz, l1_xyz, torch.cat([l0_xyz, l0_xyz], 1), l1_up)
        return {
            "l1_xyz": l1_xyz, "l1_down": l1_down, "l2_xyz": l2_xyz, "l2_down": l2_down, "l2_up": l2_up,
            "l1_up": l1_up, "global": l3.squeeze(2), "pointwise": pointwise,
        }  # fmt: skip
