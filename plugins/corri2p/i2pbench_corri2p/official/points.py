"""The authors' point encoder (pointnet2.py `PCEncoder`, layers_pc.py `GeneralKNNFusionModule`): SO-Net's
self-organising nodes on a cloud with intensity and surface normals.

Each point joins its nearest node_a; a first PointNet on [offset from its node's mean, intensity, normal] is max-
pooled per node and scattered back; a second PointNet on [point feature, its node's max] is max-pooled per node
(node_a features). Each node_b gathers its 16 nearest node_a means with their features (kNN fusion: a 2-layer 1x1
MLP on [offset, feature], max over the 16, concatenated back, another 2-layer MLP, max again); a final PointNet on
[node_b, feature] max-pooled over the nodes gives the cloud's global feature.

The per-node maximum: the authors' code asks a CUDA kernel (`index_max.forward_cuda_shared_mem`) for the index of
each node's largest feature and gathers it; a scatter max gives the same values on any device (its gradient goes
to every tied maximum instead of one: the same in eval, ties aside in training).
"""

from __future__ import annotations

import torch
from torch import nn

from .mlp import PointMLP


def nearest(query: torch.Tensor, nodes: torch.Tensor, k: int) -> torch.Tensor:
    """indices [B x N x k] of the k nearest of nodes [B x 3 x M] to each query [B x 3 x N], nearest first."""
    dist = torch.norm(query[:, :, :, None] - nodes[:, :, None, :], dim=1)
    return dist.topk(k, dim=2, largest=False, sorted=True).indices


def gather_columns(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """values [B x C x M] at index [B x N x k] -> [B x C x N x k]."""
    flat = index.reshape(len(index), 1, -1).expand(-1, values.shape[1], -1)
    return values.gather(2, flat).view(*values.shape[:2], *index.shape[1:])


def node_max(feats: torch.Tensor, owner: torch.Tensor, nodes: int) -> torch.Tensor:
    """per node and channel the largest of feats [B x C x N] over the points it owns (owner [B x N]) -> [B x C x M];
    0 for a node owning no point."""
    index = owner[:, None].expand(-1, feats.shape[1], -1)
    empty = feats.new_zeros(*feats.shape[:2], nodes)
    return empty.scatter_reduce(2, index, feats, "amax", include_self=False)


class KNNFusion(nn.Module):
    """node_b features from the K nearest node_a means and their features (GeneralKNNFusionModule)."""

    def __init__(self, cin: int, before: tuple[int, ...], after: tuple[int, ...], k: int) -> None:
        super().__init__()
        self.k = k
        self.before = PointMLP(cin, before, dims=2)
        self.after = PointMLP(2 * before[-1], after, dims=2)

    def forward(self, query: torch.Tensor, database: torch.Tensor, feats: torch.Tensor) -> torch.Tensor:
        """query [B x 3 x Mb], database [B x 3 x Ma] with feats [B x C x Ma] -> [B x C' x Mb]."""
        knn = nearest(query, database, self.k)
        offsets = gather_columns(database, knn) - query[..., None]
        x = self.before(torch.cat([offsets, gather_columns(feats, knn)], 1))
        x = torch.cat([x.amax(3, keepdim=True).expand_as(x), x], 1)
        return self.after(x).amax(3)


class PointEncoder(nn.Module):
    """SO-Net encoder: (cloud, intensity, normals, node_a, node_b) -> per-point, per-node and global features."""

    def __init__(self, ca: int = 64, cb: int = 256, cg: int = 512, k_ab: int = 16, k_point_a: int = 3) -> None:
        super().__init__()
        self.k_point_a = k_point_a
        self.first = PointMLP(3 + 1 + 3, (ca // 2,) * 3)
        self.second = PointMLP(ca, (ca, ca))
        self.knn = KNNFusion(3 + ca, (cb, cb), (2 * cb, cb), k_ab)
        self.last = PointMLP(3 + cb, (cg // 2, cg))

    def forward(
        self, pc: torch.Tensor, intensity: torch.Tensor, normals: torch.Tensor, node_a: torch.Tensor,
        node_b: torch.Tensor,
    ) -> dict[str, torch.Tensor]:  # fmt: skip
        """pc, normals [B x 3 x N], intensity [B x 1 x N], node_a [B x 3 x Ma], node_b [B x 3 x Mb] -> a dict:
        `centers` [B x 3 x N] (each point's node mean), `point_node_a` [B x N x k] (nearest node_a first),
        `node_a_mean` [B x 3 x Ma], `first` [B x Ca/2 x N], `second` [B x Ca x N], `node_a` [B x Ca x Ma],
        `node_b` [B x Cb x Mb], `global` [B x Cg x 1]."""
        count = node_a.shape[2]
        knn = nearest(pc, node_a, self.k_point_a)
        owner = knn[:, :, 0]
        members = torch.zeros(len(pc), count, dtype=pc.dtype, device=pc.device)
        members.scatter_add_(1, owner, torch.ones_like(owner, dtype=pc.dtype))
        occupied = (members > 0).to(pc.dtype)[:, None]
        sums = pc.new_zeros(len(pc), 3, count).scatter_add_(2, owner[:, None].expand(-1, 3, -1), pc)
        mean = sums / (members[:, None] + 1e-5)
        centres = mean.gather(2, owner[:, None].expand(-1, 3, -1))
        centred = pc - centres
        first = self.first(torch.cat([centred, intensity, normals], 1))
        pooled = node_max(first, owner, count) * occupied
        back = pooled.gather(2, owner[:, None].expand(-1, pooled.shape[1], -1))
        second = self.second(torch.cat([first, back], 1))
        feats_a = node_max(second, owner, count) * occupied
        feats_b = self.knn(node_b, mean, feats_a)
        glob = self.last(torch.cat([node_b, feats_b], 1)).amax(2, keepdim=True)
        return {"centers": centres, "point_node_a": knn, "node_a_mean": mean, "first": first, "second": second,
                "node_a": feats_a, "node_b": feats_b, "global": glob}  # fmt: skip
