"""PointNet++ building blocks: point grouping (farthest point sampling, ball query, 3-NN), the shared MLPs, set
abstraction and inverse-distance interpolation, with the cloud normalisation and the frame-seeded subset.

EdgeRegNet's point encoder brought them; CorrI2P's and DeepI2P's point branches and exchangers use them too, which is
why they live in the core: a change here moves the cache key of every component built on them (see `i2pbench.layers`).
Grouping runs in the compiled CPU kernels (kernels.py) for float32 CPU tensors and in the torch references otherwise.
"""

from __future__ import annotations

import zlib
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..types import Frame
from . import kernels
from .canonical import canonical_yaw

REVISION = 1  # bump when an output of this module changes for the same inputs (see i2pbench.layers)


def compiled(*tensors: torch.Tensor) -> bool:
    """whether the grouping of these tensors runs in the compiled CPU kernels (kernels.py) rather than in torch."""
    return all(t.device.type == "cpu" and t.dtype == torch.float32 for t in tensors)


def farthest_point_sampling(xyz: torch.Tensor, n: int, start: int = 0) -> torch.Tensor:
    """xyz [B x N x 3] -> [B x n] indices, each the point farthest from those chosen before (first = start).

    float32 CPU tensors go to the compiled kernel (same indices), others to `farthest_point_sampling_torch`."""
    if compiled(xyz):
        return torch.from_numpy(kernels.farthest_point_sampling(xyz.detach().numpy(), n, start))
    return farthest_point_sampling_torch(xyz, n, start)


def farthest_point_sampling_torch(xyz: torch.Tensor, n: int, start: int = 0) -> torch.Tensor:
    """the reference `farthest_point_sampling` in torch ops, and the path for GPU tensors.

    The arithmetic is that of the PointNet++ code the official sizes follow (`torch.max` over
    `sum((xyz - centroid) ** 2, -1)`): each square rounded to float32, summed x + y, then + z, and the first index
    at an exact tie. Batched over frames and free of host syncs (the chosen point is gathered by a device index,
    never `.item()`), so on CUDA the loop only queues kernels. With n > N the indices repeat `start` once every
    point is taken.
    """
    batch, num, _ = xyz.shape
    index = torch.empty(batch, n, dtype=torch.long, device=xyz.device)
    dist = torch.full((batch, num), float("inf"), device=xyz.device, dtype=xyz.dtype)
    x, y, z = xyz.permute(2, 0, 1).contiguous()
    d, t = torch.empty_like(x), torch.empty_like(x)
    farthest = torch.full((batch,), start, dtype=torch.long, device=xyz.device)
    rows = torch.arange(batch, device=xyz.device)
    for i in range(n):  # the loop is inherent; every step is vectorised over B x N, in place to save allocations
        index[:, i] = farthest
        cx, cy, cz = x[rows, farthest, None], y[rows, farthest, None], z[rows, farthest, None]
        torch.sub(x, cx, out=d).square_()
        d.add_(torch.sub(y, cy, out=t).square_())  # squares rounded, then summed x + y + z: no fused multiply-add
        d.add_(torch.sub(z, cz, out=t).square_())
        torch.minimum(dist, d, out=dist)
        farthest = torch.argmax(dist, dim=1)
    return index


def ball_query(xyz: torch.Tensor, centres: torch.Tensor, radius: float, nsample: int) -> torch.Tensor:
    """first `nsample` indices (ascending) of xyz [B x N x 3] within radius of each centre [B x C x 3] -> [B x C x k].

    balls with fewer points repeat their first index; a centre taken from xyz always finds itself. float32 CPU
    tensors go to the compiled kernel, others to `ball_query_torch`; the two can differ only by a point within float
    rounding of a ball's radius.
    """
    if compiled(xyz, centres):
        return torch.from_numpy(kernels.ball_query(xyz.detach().numpy(), centres.detach().numpy(), radius, nsample))
    return ball_query_torch(xyz, centres, radius, nsample)


def ball_query_torch(
    xyz: torch.Tensor, centres: torch.Tensor, radius: float, nsample: int, chunk: int = 128
) -> torch.Tensor:
    """the reference `ball_query` in torch ops (a distance matrix per chunk of centres), and the path for GPUs."""
    num = xyz.shape[1]
    k = min(nsample, num)
    order = torch.arange(num, device=xyz.device, dtype=xyz.dtype)  # exact in float up to 2^24 points
    sq = (xyz * xyz).sum(-1)[:, None, :]
    xyz_t = xyz.transpose(1, 2)
    out = []
    for part in centres.split(chunk, dim=1):  # chunks bound the [B x chunk x N] distance matrix
        dist2 = torch.baddbmm(sq, part, xyz_t, alpha=-2).add_((part * part).sum(-1, keepdim=True))
        key = dist2.gt_(radius**2).mul_(num).add_(order)  # index inside the ball, index + N outside
        first = key.topk(k, dim=-1, largest=False).values.long()
        out.append(torch.where(first >= num, first[..., :1], first))
    index = torch.cat(out, 1) if out else centres.new_zeros((len(xyz), 0, k), dtype=torch.long)
    return index if k == nsample else torch.cat([index, index[..., :1].expand(-1, -1, nsample - k)], -1)


def gather(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """rows of values [B x N x C] at index [B x ...] -> [B x ... x C]."""
    flat = index.reshape(len(index), -1)
    picked = values.gather(1, flat[..., None].expand(-1, -1, values.shape[-1]))
    return picked.reshape(*index.shape, values.shape[-1])


def three_nn(xyz: torch.Tensor, known: torch.Tensor) -> torch.Tensor:
    """indices of the 3 nearest of known [B x K x 3] for each xyz [B x M x 3], nearest first -> [B x M x 3] (fewer if
    K < 3). float32 CPU tensors go to a k-d tree (kernels.py), others to `three_nn_torch`."""
    if compiled(xyz, known):
        return torch.from_numpy(kernels.three_nn(xyz.detach().numpy(), known.detach().numpy()))
    return three_nn_torch(xyz, known)


def three_nn_torch(xyz: torch.Tensor, known: torch.Tensor) -> torch.Tensor:
    """the reference `three_nn`: a distance matrix and its 3 smallest per row."""
    return torch.cdist(xyz, known).topk(min(3, known.shape[1]), dim=-1, largest=False).indices


def interpolate(xyz: torch.Tensor, known: torch.Tensor, feats: torch.Tensor, nearest: torch.Tensor) -> torch.Tensor:
    """inverse-distance mean of feats [B x K x C] at the `nearest` [B x M x 3] of known [B x K x 3] -> [B x M x C]."""
    dist = (xyz[:, :, None] - gather(known, nearest)).norm(dim=-1)  # exact differences: cdist's matmul form loses
    # digits to cancellation for close pairs, the very pairs whose inverse distance dominates the weights
    weight = 1.0 / dist.clamp(min=1e-8)
    weight = weight / weight.sum(-1, keepdim=True)
    return (gather(feats, nearest) * weight[..., None]).sum(-2)


class SharedMLP(nn.Sequential):
    """1x1 convs with GroupNorm + ReLU on [B x C x ...] tensors, computed channels-last.

    Each 1x1 conv runs as one matrix product over the channel axis (torch's 1x1 convolution takes its im2col path on
    one thread, ~3x slower), and group norm and the caller's max over a ball read channels-last strides: the layers
    and state-dict keys are those of the plain nn.Sequential of convolutions, so checkpoints load unchanged.
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = x.movedim(1, -1)  # [B x ... x C]; a free view when x is channels-last, as SetAbstraction builds it
        for layer in self:
            if isinstance(layer, nn.Conv2d):
                h = F.linear(h, layer.weight.flatten(1), layer.bias)
            elif isinstance(layer, nn.GroupNorm):
                h = layer(h.movedim(-1, 1)).movedim(1, -1)
            else:
                h = layer(h)
        return h.movedim(-1, 1)


def shared_mlp(cin: int, widths: tuple[int, ...], groups: int) -> SharedMLP:
    """1x1 convs with GroupNorm + ReLU on [B x C x ...] tensors."""
    layers: list[nn.Module] = []
    for c in widths:
        layers += [nn.Conv2d(cin, c, 1, bias=False), nn.GroupNorm(min(groups, c), c), nn.ReLU(inplace=True)]
        cin = c
    return SharedMLP(*layers)


def normalize_points(xyz: torch.Tensor, reference: torch.Tensor, canonical: bool = False) -> torch.Tensor:
    """xyz [M x 3] minus the centroid of reference [N x 3], divided by reference's largest distance to it; with
    `canonical`, also turned into reference's yaw-canonical frame (canonical.py)."""
    centre = reference.mean(0)
    offsets = reference - centre
    scale = offsets.norm(dim=1).max().clamp(min=1e-6)
    if canonical:
        return (xyz - centre) @ canonical_yaw(offsets).t() / scale
    return (xyz - centre) / scale


def frame_seed(frame: Frame) -> int:
    return zlib.crc32(f"{frame.dataset}/{frame.frame_id}".encode())


def seeded_cloud(frame: Frame, num_points: int) -> np.ndarray:
    """the frame's finite returns (a corrupt one must not poison the normalisation), cut to `num_points` by a random
    subset seeded by the frame id (reproducible, and cheap next to FPS on 100k+ points) -> [N x 4] float32."""
    points = frame.points[np.isfinite(frame.points).all(1)]
    if len(points) > num_points:
        points = points[np.random.default_rng(frame_seed(frame)).choice(len(points), num_points, replace=False)]
    return np.asarray(points, np.float32)


GROUPING_KEYS = ("fps1", "ball1", "fps2", "ball2", "up", "edge")


def group(xyz: torch.Tensor, kxyz: torch.Tensor, conf: dict[str, Any]) -> dict[str, torch.Tensor]:
    """which points each layer takes, for a normalised cloud xyz [B x N x 3] and edge points kxyz [B x M x 3]:
    FPS centroids and balls of both set abstractions, and the 3-NN of the two decoding steps (all index tensors).

    Every index depends only on distances between points, so a rigid motion of the scan (the protocol's transform)
    leaves it unchanged: training computes it once per frame.
    """
    sa1, sa2 = conf["sa1"], conf["sa2"]
    with torch.no_grad():
        fps1 = farthest_point_sampling(xyz, sa1["npoint"])
        c1 = gather(xyz, fps1)
        fps2 = farthest_point_sampling(c1, sa2["npoint"])
        c2 = gather(c1, fps2)
        return {
            "fps1": fps1,
            "ball1": ball_query(xyz, c1, sa1["radius"], sa1["nsample"]),
            "fps2": fps2,
            "ball2": ball_query(c1, c2, sa2["radius"], sa2["nsample"]),
            "up": three_nn(c1, c2),
            "edge": three_nn(kxyz, c1),
        }


class SetAbstraction(nn.Module):
    """FPS centroids, ball query, shared MLP on [offset / radius, features], max over each ball."""

    def __init__(self, npoint: int, radius: float, nsample: int, cin: int, mlp: tuple[int, ...], groups: int) -> None:
        super().__init__()
        self.radius = radius  # npoint and nsample steer `group`, which runs before the network
        self.mlp = shared_mlp(cin + 3, tuple(mlp), groups)

    def forward(
        self, xyz: torch.Tensor, feats: torch.Tensor, centres: torch.Tensor, balls: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """xyz [B x N x 3], feats [B x N x C], centre indices [B x S], balls [B x S x k] -> centroids [B x S x 3],
        features [B x S x C']."""
        centroids = gather(xyz, centres)
        offsets = (gather(xyz, balls) - centroids[:, :, None]) / self.radius
        x = torch.cat([offsets, gather(feats, balls)], -1).permute(0, 3, 1, 2)  # [B x C x S x k], channels-last
        # the max over each ball taken on the contiguous [B x S x k x C]: 12x faster than over the view's last dim
        return centroids, self.mlp(x).movedim(1, -1).amax(2)
