"""The authors' 3D branch (ESRSchao/EdgeRegNet, models/cali_glue.py:189-217 and models/pointnet2_utils.py):
two PointNet++ set abstractions on the normalised cloud, then one feature propagation from the second straight onto
the edge points.

What their code does, kept here:
- the cloud (20,480 points) and the edge points are normalised by the cloud's centroid and its largest distance
  from it (KITTI_bin.py:43-56); reflectance stays as it is and is a feature of every point (4 channels);
- SA: farthest point sampling from a random first index (pointnet2_utils.py:76; here drawn from a generator seeded
  by the frame id, so a run is reproducible), the first `nsample` points of each ball in index order, the ball's
  offsets NOT divided by the radius, then [offsets, features] through Conv2d + BatchNorm2d + ReLU and a max;
- FP: the 3 nearest SA2 centroids of each edge point and inverse *squared* distance weights 1 / (d^2 + 1e-8), then
  [edge xyz + reflectance, interpolated] through Conv1d + BatchNorm1d + ReLU (the last layer too);
- squared distances of the 3-NN as the authors compute them, |a|^2 + |b|^2 - 2 a.b (pointnet2_utils.py:20-41): the
  weights of a nearly coincident pair depend on that rounding. The ball query uses exact differences (the compiled
  kernel, 8x faster than their form here); the two can disagree only on a point within float rounding (~1e-7) of a
  ball's radius, and agree on every ball of the reference frame (tests/test_edgeregnet_reference.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import BatchedStage, Encoder3D, Frame, Keypoints3D, StageError
from i2pbench.layers import pointnet2
from i2pbench.layers.pointnet2 import farthest_point_sampling, frame_seed, gather, seeded_cloud

CHUNK_ROWS = 4096  # ball slots per pass of a set abstraction's MLP in eval: its activations stay in a core's cache


def square_distance(src: torch.Tensor, dst: torch.Tensor) -> torch.Tensor:
    """src [B x N x 3], dst [B x M x 3] -> [B x N x M] squared distances in the authors' expanded form."""
    dist = -2 * torch.matmul(src, dst.transpose(1, 2))
    dist += (src**2).sum(-1)[:, :, None]
    return dist + (dst**2).sum(-1)[:, None, :]


def ball_query(xyz: torch.Tensor, centres: torch.Tensor, radius: float, nsample: int, chunk: int = 256) -> torch.Tensor:
    """the first `nsample` indices (ascending) of xyz [B x N x 3] within radius of each centre [B x S x 3], a short
    ball padded with its first -> [B x S x nsample] (pointnet2_utils.py:88-108), with the authors' distances: the
    reference the faster `pointnet2.ball_query` (exact differences, compiled on a CPU) is tested against."""
    num = xyz.shape[1]
    out = []
    for part in centres.split(chunk, dim=1):  # chunks bound the [B x chunk x N] distance matrix
        order = torch.arange(num, device=xyz.device).expand(*part.shape[:2], num)
        key = torch.where(square_distance(part, xyz) > radius**2, num, order)
        first = key.topk(min(nsample, num), dim=-1, largest=False).values.sort(-1).values
        out.append(torch.where(first == num, first[..., :1], first))
    return torch.cat(out, 1)


def three_nn(xyz: torch.Tensor, known: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """the 3 nearest of known [B x K x 3] for each xyz [B x M x 3] -> (squared distances, indices), [B x M x 3]:
    the first 3 of the authors' sort of each row, ties in index order (a stable sort).

    Only 4 candidates per row are ordered (a full sort of the [M x K] distances took 0.2 s of the branch's 1.1 s);
    a row whose 3rd and 4th candidates tie, where a lower index may lie beyond them, is sorted whole."""
    dist = square_distance(xyz, known)
    k = min(3, dist.shape[-1])
    value, index = dist.topk(min(k + 1, dist.shape[-1]), dim=-1, largest=False)
    value, index = stable_by_value(value, index)
    if value.shape[-1] > k:
        tied = value[..., k - 1] == value[..., k]
        if tied.any():
            whole = dist[tied].sort(dim=-1, stable=True)
            value[tied], index[tied] = whole.values[:, : k + 1], whole.indices[:, : k + 1]
    return value[..., :k], index[..., :k]


def stable_by_value(value: torch.Tensor, index: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """candidates (value, index) [... x c] ordered by value, equal values by index."""
    by_index = index.argsort(dim=-1)
    value, index = value.gather(-1, by_index), index.gather(-1, by_index)
    by_value = value.argsort(dim=-1, stable=True)
    return value.gather(-1, by_value), index.gather(-1, by_value)


def conv_bn(cin: int, widths: tuple[int, ...], dims: int) -> tuple[nn.ModuleList, nn.ModuleList]:
    """the authors' `mlp_convs` and `mlp_bns`: 1x1 convolutions with bias, each followed by a batch norm."""
    conv, norm = (nn.Conv2d, nn.BatchNorm2d) if dims == 2 else (nn.Conv1d, nn.BatchNorm1d)
    cins = (cin, *widths[:-1])
    return nn.ModuleList(conv(i, o, 1) for i, o in zip(cins, widths, strict=True)), nn.ModuleList(map(norm, widths))


def conv_norm_relu(conv: nn.Module, bn: nn.modules.batchnorm._BatchNorm, x: torch.Tensor) -> torch.Tensor:
    """relu(bn(conv(x))) of a 1x1 conv on a channels-last x [B x ... x C]. In eval mode the conv's bias and the
    norm's affine map are applied in place after the matrix product (a bias in the product costs a broadcast copy
    the size of the output); the same arithmetic as the authors' up to float rounding."""
    weight = conv.weight.flatten(1)
    if bn.training or not bn.track_running_stats:
        return F.relu(bn(F.linear(x, weight, conv.bias).movedim(-1, 1)).movedim(1, -1))
    scale = bn.weight * (bn.running_var + bn.eps).rsqrt()
    return F.linear(x, weight).mul_(scale).add_((conv.bias - bn.running_mean) * scale + bn.bias).relu_()


def folded(conv: nn.Module, bn: nn.modules.batchnorm._BatchNorm) -> tuple[torch.Tensor, torch.Tensor]:
    """an eval-mode 1x1 conv + batch norm as one linear map: weight [C' x C], bias [C']."""
    scale = bn.weight * (bn.running_var + bn.eps).rsqrt()
    return conv.weight.flatten(1) * scale[:, None], (conv.bias - bn.running_mean) * scale + bn.bias


class SetAbstraction(nn.Module):
    """[ball offsets, ball features] through the shared MLP, max over the ball."""

    def __init__(self, cin: int, mlp: tuple[int, ...]) -> None:
        super().__init__()
        self.mlp_convs, self.mlp_bns = conv_bn(cin + 3, mlp, 2)

    def forward(
        self, xyz: torch.Tensor, feats: torch.Tensor, centres: torch.Tensor, balls: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """xyz [B x N x 3], feats [B x N x C], centre indices [B x S], balls [B x S x k] -> centroids [B x S x 3],
        features [B x S x C']."""
        if any(bn.training or not bn.track_running_stats for bn in self.mlp_bns):
            return self.dense(xyz, feats, centres, balls)
        return self.ragged(xyz, feats, centres, balls)

    def dense(
        self, xyz: torch.Tensor, feats: torch.Tensor, centres: torch.Tensor, balls: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """`forward` on every slot of every ball, as the authors compute it: the path with batch statistics."""
        centroids = gather(xyz, centres)
        offsets = gather(xyz, balls) - centroids[:, :, None]
        # [B x k x S x C]: a channels-last [B x C x k x S], the authors' layout, so each 1x1 conv is one matrix
        # product over C and the batch norm reads channels-last strides (4x faster than NCHW convolutions here)
        x = torch.cat([offsets, gather(feats, balls)], -1).transpose(1, 2).contiguous()
        for conv, bn in zip(self.mlp_convs, self.mlp_bns, strict=True):
            x = conv_norm_relu(conv, bn, x)
        return centroids, x.amax(1)

    def ragged(
        self, xyz: torch.Tensor, feats: torch.Tensor, centres: torch.Tensor, balls: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """`forward` in eval mode on each ball's own points, balls of like size together, in cache-sized blocks.

        A short ball repeats its first index up to k; a repeat is the same row through the MLP, so the max over the
        ball is the same without it (11% of SA1's slots on the reference KITTI frame, 72% on the synthetic one).
        Balls sorted by their own count are taken about CHUNK_ROWS slots at a time as a dense [s x k' x C] block,
        k' the block's largest count (the others padded with their repeats, as the authors pad): the products run on
        blocks that stay in cache (3x the rate of one product over the whole [B*S*k x C] tensor here) and the max
        over a contiguous axis. Each norm is folded into its convolution and the ReLU taken after the max (it
        commutes with it); where the grouped input is wider than the first layer's output, that layer runs once per
        point and once per centre (W [p - c, f] = W [p, f] - W_p c) and the block gathers its narrower output."""
        batch, num = xyz.shape[:2]
        centroids = gather(xyz, centres)
        table = torch.cat([xyz, feats], -1).reshape(batch * num, -1)  # [p, f] of every point
        members = (balls + torch.arange(batch, device=balls.device)[:, None, None] * num).flatten(0, 1)
        counts = (members[:, 1:] != members[:, :1]).sum(-1) + 1  # ascending, then the first repeated
        order = counts.argsort(descending=True)
        centre = centroids.reshape(-1, 3)
        layers = [folded(conv, bn) for conv, bn in zip(self.mlp_convs, self.mlp_bns, strict=True)]
        per_point = table.shape[1] > layers[0][0].shape[0]
        if per_point:
            weight, bias = layers.pop(0)
            table, centre = torch.addmm(bias, table, weight.t()), centre @ weight[:, :3].t()
        out = xyz.new_empty(len(counts), layers[-1][0].shape[0])
        sizes, start = counts[order].tolist(), 0
        while start < len(order):
            k = sizes[start]
            block = order[start : start + max(1, CHUNK_ROWS // k)]
            start += len(block)
            x = table.index_select(0, members.index_select(0, block)[:, :k].flatten()).view(len(block), k, -1)
            if per_point:
                x = x.sub_(centre.index_select(0, block)[:, None]).relu_()
            else:
                x[..., :3] -= centre.index_select(0, block)[:, None]
            x = x.view(len(block) * k, -1)
            for i, (weight, bias) in enumerate(layers):
                x = torch.addmm(bias, x, weight.t())
                if i < len(layers) - 1:
                    x.relu_()
            out[block] = x.view(len(block), k, -1).amax(1)
        return centroids, out.relu_().view(batch, -1, out.shape[-1])


class Propagation(nn.Module):
    """inverse squared-distance interpolation of SA2 features at the edge points, then the shared MLP."""

    def __init__(self, cin: int, mlp: tuple[int, ...]) -> None:
        super().__init__()
        self.mlp_convs, self.mlp_bns = conv_bn(cin, mlp, 1)

    def forward(self, xyz: torch.Tensor, own: torch.Tensor, known: torch.Tensor, feats: torch.Tensor) -> torch.Tensor:
        """edge points xyz [B x M x 3] with their own features [B x M x 4], SA2 centroids known [B x K x 3] with
        feats [B x K x C] -> [B x M x C']."""
        dist, index = three_nn(xyz, known)
        weight = 1.0 / (dist + 1e-8)
        weight = weight / weight.sum(-1, keepdim=True)
        x = torch.cat([own, (gather(feats, index) * weight[..., None]).sum(2)], -1)
        for conv, bn in zip(self.mlp_convs, self.mlp_bns, strict=True):
            x = conv_norm_relu(conv, bn, x)
        return x


def normalize(points: torch.Tensor, cloud: torch.Tensor) -> torch.Tensor:
    """points [M x 4] with xyz minus cloud's [N x 4] centroid, divided by its largest distance (KITTI_bin.py:43)."""
    centre = cloud[:, :3].mean(0)
    scale = (cloud[:, :3] - centre).norm(dim=1).max().clamp(min=1e-6)
    return torch.cat([(points[:, :3] - centre) / scale, points[:, 3:]], 1)


class OfficialPointNet2(BatchedStage, Encoder3D):
    """The authors' PointNet++ descriptors of LiDAR edge points (module docstring)."""

    name = "pointnet2-official"
    default_conf: dict[str, Any] = {
        "descriptor_dim": 256,  # D, the FP's last width
        "num_points": 20480,  # the cloud the authors' data files hold (KITTI_bin.py:112)
        "sa1": {"npoint": 5120, "radius": 0.1, "nsample": 256, "mlp": (32, 32, 64)},  # cali_glue.py:189
        "sa2": {"npoint": 1280, "radius": 0.2, "nsample": 128, "mlp": (64, 64, 128)},  # cali_glue.py:190
        "fp_mlp": (128, 256, 256),  # cali_glue.py:192, on [edge xyz + reflectance (4), SA2 features]
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        c = self.conf
        self.sa1 = SetAbstraction(4, tuple(c["sa1"]["mlp"]))
        self.sa2 = SetAbstraction(c["sa1"]["mlp"][-1], tuple(c["sa2"]["mlp"]))
        self.fp = Propagation(4 + c["sa2"]["mlp"][-1], tuple(c["fp_mlp"]))

    def prepare(
        self, frame: Frame, kp3d: Keypoints3D, device: torch.device | str = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's network inputs: the normalised cloud [N x 4] and edge points [M x 4], and the grouping."""
        if not np.isfinite(kp3d.xyz).all() or not np.isfinite(kp3d.reflectance).all():
            raise StageError(self.label, "3D keypoints with non-finite coordinates or reflectance (corrupt scan?)")
        # the authors' files hold 20,480 points chosen by a script they have not released: a seeded subset here
        cloud = torch.from_numpy(seeded_cloud(frame, self.conf["num_points"]))
        edges = torch.from_numpy(np.c_[kp3d.xyz, kp3d.reflectance].astype(np.float32))
        inputs = {"xyz": normalize(cloud, cloud), "edges": normalize(edges, cloud)}
        grouping = cache.get("grouping") if cache is not None else None
        if grouping is None:
            starts = np.random.default_rng(frame_seed(frame)).integers(0, [len(cloud), self.conf["sa1"]["npoint"]])
            grouping = self.group(inputs["xyz"], *map(int, starts))
            if cache is not None:
                cache["grouping"] = grouping
        return {k: v.to(device) for k, v in {**inputs, **grouping}.items()}

    def group(self, xyz: torch.Tensor, start1: int = 0, start2: int = 0, fps: tuple | None = None) -> dict:
        """FPS centres and balls of both set abstractions for a cloud xyz [N x 4] (one frame); `fps` gives the two
        FPS index arrays instead (the authors' draws, to compare with their outputs)."""
        sa1, sa2 = self.conf["sa1"], self.conf["sa2"]
        with torch.no_grad():
            points = xyz[None, :, :3].contiguous()
            fps1 = farthest_point_sampling(points, sa1["npoint"], start1) if fps is None else fps[0][None]
            c1 = gather(points, fps1)
            fps2 = farthest_point_sampling(c1, sa2["npoint"], start2) if fps is None else fps[1][None]
            ball1 = pointnet2.ball_query(points, c1, sa1["radius"], sa1["nsample"])
            ball2 = pointnet2.ball_query(c1, gather(c1, fps2), sa2["radius"], sa2["nsample"])
        return {"fps1": fps1[0], "ball1": ball1[0], "fps2": fps2[0], "ball2": ball2[0]}

    def forward(self, inputs: dict[str, torch.Tensor], trace: dict | None = None) -> torch.Tensor:
        """`prepare`d frames: xyz [B x N x 4], edges [B x M x 4] and the grouping -> descriptors [B x M x D];
        `trace`, when given, receives the SA outputs."""
        xyz = inputs["xyz"]
        c1, f1 = self.sa1(xyz[..., :3], xyz, inputs["fps1"], inputs["ball1"])
        c2, f2 = self.sa2(c1, f1, inputs["fps2"], inputs["ball2"])
        if trace is not None:
            trace.update(sa1=f1, sa2=f2)
        edges = inputs["edges"]
        return self.fp(edges[..., :3], edges, c2, f2)
