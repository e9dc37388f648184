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

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import BatchedStage, Encoder3D, Frame, Keypoints3D, StageError
from i2pbench.layers.pointnet2 import SetAbstraction, group, interpolate, normalize_points, seeded_cloud, shared_mlp


class PointNet2Encoder(BatchedStage, Encoder3D):
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
        "canonical_yaw": False,  # True: the cloud in its yaw-canonical frame (layers/canonical.py; not the paper's)
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        c, g = self.conf, self.conf["groups"]
        self.sa1 = SetAbstraction(**c["sa1"], cin=1, groups=g)
        self.sa2 = SetAbstraction(**c["sa2"], cin=c["sa1"]["mlp"][-1], groups=g)
        self.fp = shared_mlp(c["sa2"]["mlp"][-1] + c["sa1"]["mlp"][-1], tuple(c["fp_mlp"]), g)
        widths = (c["fp_mlp"][-1] + 4, *c["head_mlp"])
        layers: list[nn.Module] = []
        for cin, cout in zip(widths[:-1], widths[1:], strict=True):
            layers += [nn.Linear(cin, cout), nn.LayerNorm(cout), nn.ReLU(inplace=True)]
        self.head = nn.Sequential(*layers, nn.Linear(widths[-1], c["descriptor_dim"]))

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
        cloud = torch.from_numpy(seeded_cloud(frame, self.conf["num_points"]))
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
