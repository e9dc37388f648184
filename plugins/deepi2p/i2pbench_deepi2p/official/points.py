"""DeepI2P's SO-Net-style point encoder (authors' `models/networks_pc.py` PCEncoder, `layers_pc.py`
GeneralKNNFusionModule): points clustered to their nearest node a, per-cluster max pooling twice, a kNN fusion of the
a-node features at the b nodes, and the cloud's global feature.

`index_max` (their CUDA kernel) is `i2pbench.layers.cluster_max`, which computes the same forward values.
"""

from __future__ import annotations

import torch
from torch import nn

from i2pbench.layers.cluster_max import cluster_max

from .blocks import PointMLP, gather_columns, nearest


class KNNFusion(nn.Module):
    """per b node: its K nearest a nodes (offsets + features) through an MLP, max-pooled, the max concatenated back
    to each neighbour, a second MLP, max-pooled again (the authors' GeneralKNNFusionModule)."""

    def __init__(self, cin: int, before: tuple[int, ...], after: tuple[int, ...]) -> None:
        super().__init__()
        self.layers_before = PointMLP(cin, before, dims=2).layers
        self.layers_after = PointMLP(2 * before[-1], after, dims=2).layers

    def forward(self, query: torch.Tensor, database: torch.Tensor, features: torch.Tensor, k: int) -> torch.Tensor:
        index = nearest(query, database, k)
        offsets = gather_columns(database, index) - query[:, :, :, None]
        x = torch.cat([offsets, gather_columns(features, index)], dim=1)
        for layer in self.layers_before:
            x = layer(x)
        x = torch.cat([x.max(dim=3, keepdim=True)[0].expand_as(x), x], dim=1)
        for layer in self.layers_after:
            x = layer(x)
        return x.max(dim=3)[0]


class PointEncoder(nn.Module):
    """[B x 3 x N] points, intensity [B x 1 x N], normals [B x 3 x N], nodes a [B x 3 x Ma], b [B x 3 x Mb] ->
    per-point, per-node and global features (Ca = 64, Cb = 256, Cg = 512 as the authors' KeypointDetector)."""

    def __init__(self, ca: int = 64, cb: int = 256, cg: int = 512, k_ab: int = 16, k_point_a: int = 3) -> None:
        super().__init__()
        self.k_ab, self.k_point_a = k_ab, k_point_a
        self.first_pointnet = PointMLP(7, (ca // 2,) * 3)
        self.second_pointnet = PointMLP(ca, (ca, ca))
        self.knnlayer = KNNFusion(3 + ca, (cb, cb), (2 * cb, cb))
        self.final_pointnet = PointMLP(3 + cb, (cg // 2, cg))

    def forward(
        self, pc: torch.Tensor, intensity: torch.Tensor, sn: torch.Tensor, node_a: torch.Tensor, node_b: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        ma = node_a.shape[2]
        knn_a = nearest(pc, node_a, self.k_point_a)
        cluster = knn_a[:, :, 0]
        member = nn.functional.one_hot(cluster, ma).to(pc.dtype)  # B x N x Ma
        occupied = (member.amax(dim=1) > 0).to(pc.dtype)[:, None]  # B x 1 x Ma
        count = member.sum(dim=1)[:, None]
        cluster_mean = (pc[:, :, :, None] * member[:, None]).sum(dim=2) / (count + 1e-5)
        centres = torch.gather(cluster_mean, 2, cluster[:, None].expand(-1, 3, -1))
        first = self.first_pointnet(torch.cat([pc - centres, intensity, sn], dim=1))
        first_max = cluster_max(first, cluster, ma) * occupied
        scattered = torch.gather(first_max, 2, cluster[:, None].expand(-1, first.shape[1], -1))
        second = self.second_pointnet(torch.cat([first, scattered], dim=1))
        node_a_features = cluster_max(second, cluster, ma) * occupied
        node_b_features = self.knnlayer(node_b, cluster_mean, node_a_features, self.k_ab)
        final = self.final_pointnet(torch.cat([node_b, node_b_features], dim=1))
        return {
            "pc_center": centres, "cluster_mean": cluster_mean, "node_a_min_k_idx": knn_a,
            "first_pn_out": first, "second_pn_out": second, "node_a_features": node_a_features,
            "node_b_features": node_b_features, "global_feature": final.max(dim=2, keepdim=True)[0],
        }  # fmt: skip
