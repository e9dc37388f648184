"""PointNet++ encoder: two set-abstraction layers on the cloud, feature propagation onto the 3D edge points.

Choices the paper leaves open:
- the cloud is cut to `num_points` by a random subset seeded by the frame id (reproducible, and cheap next to FPS on
  100k+ points); a smaller cloud is used whole;
- cloud and edge points are normalised together: minus the cloud's centroid, divided by its largest distance to it;
- ball query keeps the first `nsample` points of each ball in index order (as PointNet++'s CUDA kernel; the cloud is a
  random permutation, so this is a random draw from the ball), padding with the first; offsets are divided by radius;
- shared MLPs use GroupNorm, not BatchNorm: one frame per step makes batch statistics meaningless;
- decoding follows PointNet++'s: 3-NN inverse-distance interpolation from SA2 to SA1 centroids, then from SA1 to the
  edge points, whose own normalised xyz and reflectance are concatenated before the last MLP.
"""

from __future__ import annotations

import zlib
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import Encoder3D, Frame, Keypoints3D, LearnedComponent, StageError

from . import kernels
from .canonical import canonical_yaw


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

    Batched over frames and free of host syncs (the chosen point is gathered by a device index, never `.item()`), so
    on CUDA the loop only queues kernels. With n > N the indices repeat `start` once every point is taken.
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
        d.addcmul_(torch.sub(y, cy, out=t), t)
        d.addcmul_(torch.sub(z, cz, out=t), t)
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


class PointNet2Encoder(LearnedComponent, Encoder3D):
    """Descriptors of LiDAR edge points from a two-level PointNet++ on the (sub-sampled) cloud."""

    name = "pointnet2"
    default_conf: dict[str, Any] = {
        "descriptor_dim": 256,  # D, the output width
        "num_points": 20480,  # cloud size fed to PointNet++ (seeded random subset by frame id)
        "sa1": {"npoint": 5120, "radius": 0.1, "nsample": 32, "mlp": (64, 64, 128)},  # radius in normalised units
        "sa2": {"npoint": 1280, "radius": 0.2, "nsample": 32, "mlp": (128, 128, 256)},
        "fp_mlp": (256, 256),  # decoder SA2 -> SA1 centroids, on [interpolated SA2, SA1] features
        "head_mlp": (256,),  # hidden widths on [interpolated, xyz, reflectance] at the edge points, then Linear to D
        "groups": 8,  # GroupNorm groups in the shared MLPs
        "normalize_descriptors": True,  # L2-normalise outputs, so both modalities enter the exchanger at one scale
        "canonical_yaw": False,  # True: the cloud in its yaw-canonical frame (canonical.py; not the paper's)
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        for sa in ("sa1", "sa2"):  # a partial override of a set-abstraction layer keeps the other defaults
            self.conf[sa] = {**self.default_conf[sa], **self.conf[sa]}
        c, g = self.conf, self.conf["groups"]
        self.sa1 = SetAbstraction(**c["sa1"], cin=1, groups=g)
        self.sa2 = SetAbstraction(**c["sa2"], cin=c["sa1"]["mlp"][-1], groups=g)
        self.fp = shared_mlp(c["sa2"]["mlp"][-1] + c["sa1"]["mlp"][-1], tuple(c["fp_mlp"]), g)
        widths = (c["fp_mlp"][-1] + 4, *c["head_mlp"])
        layers: list[nn.Module] = []
        for cin, cout in zip(widths[:-1], widths[1:], strict=True):
            layers += [nn.Linear(cin, cout), nn.LayerNorm(cout), nn.ReLU(inplace=True)]
        self.head = nn.Sequential(*layers, nn.Linear(widths[-1], c["descriptor_dim"]))

    def cloud(self, frame: Frame) -> np.ndarray:
        """the frame's finite returns, cut to `num_points` by a subset seeded by the frame id -> [N x 4]."""
        points = frame.points
        finite = np.isfinite(points).all(1)
        if not finite.all():  # a corrupt return must not poison the normalisation; clean scans keep their subset
            points = points[finite]
        if len(points) > self.conf["num_points"]:
            rng = np.random.default_rng(frame_seed(frame))
            points = points[rng.choice(len(points), self.conf["num_points"], replace=False)]
        return np.asarray(points, np.float32)

    def prepare(
        self, frame: Frame, kp3d: Keypoints3D, device: torch.device | str = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's network inputs: normalised cloud and edge points (+ reflectance) and their grouping.

        `cache` (a per-frame dict kept by the caller) holds the grouping across calls: it does not depend on the
        protocol's transform (see `group`). The inputs are made on the CPU and grouped there by the compiled
        kernels whatever the device (on a GPU the torch loop of FPS is thousands of tiny kernels), then moved.
        """
        if not np.isfinite(kp3d.xyz).all() or not np.isfinite(kp3d.reflectance).all():
            raise StageError(self.label, "3D keypoints with non-finite coordinates or reflectance (corrupt scan?)")
        cloud = torch.from_numpy(self.cloud(frame))
        edges = torch.from_numpy(np.c_[kp3d.xyz, kp3d.reflectance].astype(np.float32))
        both = normalize_points(torch.cat([cloud[:, :3], edges[:, :3]]), cloud[:, :3], self.conf["canonical_yaw"])
        inputs = {
            "xyz": both[: len(cloud)],
            "reflectance": cloud[:, 3:],
            "edge_xyz": both[len(cloud) :],
            "edge_reflectance": edges[:, 3:],
        }
        grouping = cache.get("grouping") if cache is not None else None
        if grouping is None or len(grouping["edge"]) != len(edges):
            grouping = {k: v[0] for k, v in group(inputs["xyz"][None], inputs["edge_xyz"][None], self.conf).items()}
            if cache is not None:
                cache["grouping"] = grouping
        return {k: v.to(device) for k, v in {**inputs, **grouping}.items()}

    def __call__(self, frame: Frame, kp3d: Keypoints3D) -> torch.Tensor:
        device = next(self.parameters()).device
        inputs = {k: v[None] for k, v in self.prepare(frame, kp3d, device).items()}
        return nn.Module.__call__(self, inputs)[0].float()

    def forward(self, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        """a batch of `prepare`d frames (each tensor with a leading B) -> edge-point descriptors [B x M x D].

        xyz [B x N x 3], reflectance [B x N x 1], edge_xyz [B x M x 3], edge_reflectance [B x M x 1] and the grouping
        indices; rows past a frame's own counts are padding, never gathered by its indices.
        """
        g = inputs
        xyz1, f1 = self.sa1(g["xyz"], g["reflectance"], g["fps1"], g["ball1"])
        xyz2, f2 = self.sa2(xyz1, f1, g["fps2"], g["ball2"])
        up = torch.cat([interpolate(xyz1, xyz2, f2, g["up"]), f1], -1)
        f1 = self.fp(up.transpose(1, 2)[..., None])[..., 0].transpose(1, 2)
        kxyz = g["edge_xyz"]
        x = torch.cat([interpolate(kxyz, xyz1, f1, g["edge"]), kxyz, g["edge_reflectance"]], -1)
        desc = self.head(x)
        return F.normalize(desc, dim=-1) if self.conf["normalize_descriptors"] else desc
