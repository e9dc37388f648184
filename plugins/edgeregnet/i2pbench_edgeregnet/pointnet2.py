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

from .canonical import canonical_yaw


def farthest_point_sampling(xyz: torch.Tensor, n: int, start: int = 0) -> torch.Tensor:
    """xyz [N x 3] -> [n] indices, each the point farthest from those chosen before (first = start)."""
    num = xyz.shape[0]
    n = min(n, num)
    index = torch.empty(n, dtype=torch.long, device=xyz.device)
    dist = torch.full((num,), float("inf"), device=xyz.device, dtype=xyz.dtype)
    x, y, z = xyz.t().contiguous()
    d, t = torch.empty_like(x), torch.empty_like(x)
    farthest = torch.tensor(start, device=xyz.device)
    for i in range(n):  # the loop is inherent; every step is vectorised over the N points, in place to save allocations
        index[i] = farthest
        c = xyz[farthest]
        torch.sub(x, c[0], out=d).square_()
        d.addcmul_(torch.sub(y, c[1], out=t), t)
        d.addcmul_(torch.sub(z, c[2], out=t), t)
        torch.minimum(dist, d, out=dist)
        farthest = torch.argmax(dist)
    return index


def ball_query(xyz: torch.Tensor, centres: torch.Tensor, radius: float, nsample: int, chunk: int = 128) -> torch.Tensor:
    """first `nsample` indices (ascending) of xyz [N x 3] within radius of each centre [C x 3] -> [C x nsample].

    balls with fewer points repeat their first index; a centre taken from xyz always finds itself.
    """
    num = xyz.shape[0]
    k = min(nsample, num)
    order = torch.arange(num, device=xyz.device, dtype=xyz.dtype)  # exact in float up to 2^24 points
    sq = (xyz * xyz).sum(1)
    out = [centres.new_zeros((0, k), dtype=torch.long)]
    for part in centres.split(chunk):  # chunks bound the [chunk x N] distance matrix (small chunks stay in cache)
        dist2 = torch.addmm(sq, part, xyz.t(), alpha=-2).add_((part * part).sum(1, keepdim=True))
        key = dist2.gt_(radius**2).mul_(num).add_(order)  # index inside the ball, index + N outside
        first = key.topk(k, dim=1, largest=False).values.long()
        out.append(torch.where(first >= num, first[:, :1], first))
    index = torch.cat(out)
    return index if k == nsample else torch.cat([index, index[:, :1].expand(-1, nsample - k)], 1)


def three_nn_interpolate(xyz: torch.Tensor, known: torch.Tensor, feats: torch.Tensor) -> torch.Tensor:
    """inverse-distance mean of feats [K x C] at the 3 nearest of known [K x 3] for each xyz [M x 3] -> [M x C]."""
    dist, index = torch.cdist(xyz, known).topk(min(3, known.shape[0]), dim=1, largest=False)
    weight = 1.0 / dist.clamp(min=1e-8)
    weight = weight / weight.sum(1, keepdim=True)
    return (feats[index] * weight[..., None]).sum(1)


def shared_mlp(cin: int, widths: tuple[int, ...], groups: int) -> nn.Sequential:
    """1x1 convs with GroupNorm + ReLU on [1 x C x ...] tensors."""
    layers: list[nn.Module] = []
    for c in widths:
        layers += [nn.Conv2d(cin, c, 1, bias=False), nn.GroupNorm(min(groups, c), c), nn.ReLU(inplace=True)]
        cin = c
    return nn.Sequential(*layers)


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


class SetAbstraction(nn.Module):
    """FPS centroids, ball query, shared MLP on [offset / radius, features], max over each ball."""

    def __init__(self, npoint: int, radius: float, nsample: int, cin: int, mlp: tuple[int, ...], groups: int) -> None:
        super().__init__()
        self.npoint, self.radius, self.nsample = npoint, radius, nsample
        self.mlp = shared_mlp(cin + 3, tuple(mlp), groups)

    def forward(self, xyz: torch.Tensor, feats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """xyz [N x 3], feats [N x C] -> centroids [S x 3], features [S x C']."""
        with torch.no_grad():
            centres = xyz[farthest_point_sampling(xyz, self.npoint)]
            group = ball_query(xyz, centres, self.radius, self.nsample)
        offsets = (xyz[group] - centres[:, None]) / self.radius
        x = torch.cat([offsets, feats[group]], -1).permute(2, 0, 1)[None]  # [1 x C x S x nsample]
        return centres, self.mlp(x).amax(-1)[0].t()


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

    def __call__(self, frame: Frame, kp3d: Keypoints3D) -> torch.Tensor:
        device = next(self.parameters()).device
        if not np.isfinite(kp3d.xyz).all() or not np.isfinite(kp3d.reflectance).all():
            raise StageError(self.label, "3D keypoints with non-finite coordinates or reflectance (corrupt scan?)")
        points = frame.points
        finite = np.isfinite(points).all(1)
        if not finite.all():  # a corrupt return must not poison the normalisation; clean scans keep their subset
            points = points[finite]
        if len(points) > self.conf["num_points"]:
            rng = np.random.default_rng(frame_seed(frame))
            points = points[rng.choice(len(points), self.conf["num_points"], replace=False)]
        cloud = torch.from_numpy(np.asarray(points, np.float32)).to(device)
        edges = np.concatenate([kp3d.xyz, kp3d.reflectance[:, None]], 1).astype(np.float32)
        return nn.Module.__call__(self, cloud, torch.from_numpy(edges).to(device)).float()

    def forward(self, cloud: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
        """cloud [N x 4], edge points [M x 4] (xyz, reflectance; LiDAR frame) -> descriptors [M x D]."""
        both = normalize_points(torch.cat([cloud[:, :3], edges[:, :3]]), cloud[:, :3], self.conf["canonical_yaw"])
        xyz, kxyz = both[: len(cloud)], both[len(cloud) :]
        xyz1, f1 = self.sa1(xyz, cloud[:, 3:])
        xyz2, f2 = self.sa2(xyz1, f1)
        up = torch.cat([three_nn_interpolate(xyz1, xyz2, f2), f1], 1)
        f1 = self.fp(up.t()[None, :, :, None])[0, :, :, 0].t()
        x = torch.cat([three_nn_interpolate(kxyz, xyz1, f1), kxyz, edges[:, 3:]], 1)
        desc = self.head(x)
        return F.normalize(desc, dim=-1) if self.conf["normalize_descriptors"] else desc
