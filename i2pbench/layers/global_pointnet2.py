"""A two-level PointNet++ point encoder with the cloud's global feature: [local (D - G) | global (G)] per 3D keypoint.

The global feature is a shared MLP on the second level's nodes ([position, features]) max-pooled over them; each
keypoint's local part reads the interpolated first-level features, its normalised position and reflectance, and its
offsets from its 3 nearest first-level nodes, through an MLP normalised over the frame's keypoints (frame_norm.py).
CorrI2P's point branch brought it (its module says how it differs from the paper); DeepI2P's is the same network at
another input size, so both plugins subclass it and give it their name and defaults.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from ..errors import StageError
from ..stages.components import Encoder3D
from ..stages.learned import BatchedStage
from ..types import Frame, Keypoints3D
from .frame_norm import FrameMLP
from .pointnet2 import SetAbstraction, gather, group, interpolate, normalize_points, seeded_cloud, shared_mlp

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)
NEAREST_NODES = 3  # first-level nodes each keypoint reads (the 3-NN of the feature propagation)


class GlobalPointNet2Encoder(BatchedStage, Encoder3D):
    """Per-keypoint [local | global] descriptors from a two-level PointNet++ on the (sub-sampled) cloud."""

    default_conf: dict[str, Any] = {
        "descriptor_dim": 640,  # D: local (D - G) + global (G) channels per keypoint
        "global_dim": 512,  # G: the cloud's global feature (the paper's 512)
        "num_points": 40960,  # cloud size (seeded random subset by frame id; the paper's 40,960)
        "sa1": {"npoint": 128, "radius": 0.1, "nsample": 64, "mlp": (32, 32, 64)},  # the paper's first 128 nodes, 64 ch
        "sa2": {"npoint": 128, "radius": 0.3, "nsample": 16, "mlp": (256, 256)},  # second 128 nodes, 256 ch, k = 16
        "global_mlp": (256, 512),  # shared MLP on [xyz, SA2 features] before the max (ends at global_dim)
        "fp_mlp": (256,),  # decoder SA2 -> SA1 nodes, on [interpolated SA2, SA1] features
        "head_mlp": (256, 256),  # hidden widths on [interpolated, xyz, reflectance, node offsets] at the keypoints
        "groups": 8,  # GroupNorm groups in the shared MLPs
        "normalize_descriptors": True,  # L2-normalise the local part
        "canonical_yaw": False,  # True: the cloud in its yaw-canonical frame (layers/canonical.py; our addition)
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        c, g = self.conf, self.conf["groups"]
        local = c["descriptor_dim"] - c["global_dim"]
        if local < 1 or c["global_mlp"][-1] != c["global_dim"]:
            raise ValueError(f"{self.label}: needs descriptor_dim > global_dim and global_mlp ending at global_dim")
        self.sa1 = SetAbstraction(**c["sa1"], cin=1, groups=g)
        self.sa2 = SetAbstraction(**c["sa2"], cin=c["sa1"]["mlp"][-1], groups=g)
        self.global_mlp = shared_mlp(3 + c["sa2"]["mlp"][-1], tuple(c["global_mlp"]), g)
        self.fp = shared_mlp(c["sa2"]["mlp"][-1] + c["sa1"]["mlp"][-1], tuple(c["fp_mlp"]), g)
        self.head = FrameMLP((c["fp_mlp"][-1] + 4 + 3 * NEAREST_NODES, *c["head_mlp"], local))

    def prepare(
        self, frame: Frame, kp3d: Keypoints3D, device: torch.device | str = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's inputs: normalised cloud and keypoints (+ reflectance) and their grouping, which `cache` keeps
        across calls (it depends only on distances between points, which the protocol's transform keeps)."""
        if not np.isfinite(kp3d.xyz).all() or not np.isfinite(kp3d.reflectance).all():
            raise StageError(self.label, "3D keypoints with non-finite coordinates or reflectance (corrupt scan?)")
        cloud = torch.from_numpy(seeded_cloud(frame, self.conf["num_points"])).to(device)
        if len(cloud) == 0:
            raise StageError(self.label, "a scan with no finite point")
        keys = torch.from_numpy(np.c_[kp3d.xyz, kp3d.reflectance].astype(np.float32)).to(device)
        both = normalize_points(torch.cat([cloud[:, :3], keys[:, :3]]), cloud[:, :3], self.conf["canonical_yaw"])
        inputs = {
            "xyz": both[: len(cloud)],
            "reflectance": cloud[:, 3:],
            "key_xyz": both[len(cloud) :],
            "key_reflectance": keys[:, 3:],
            "num_keys": torch.tensor(len(keys), device=device),
        }
        grouping = cache.get("grouping") if cache is not None else None
        if grouping is None or len(grouping["edge"]) != len(keys):
            grouping = {k: v[0] for k, v in group(inputs["xyz"][None], inputs["key_xyz"][None], self.conf).items()}
            if cache is not None:
                cache["grouping"] = {k: v.cpu() for k, v in grouping.items()}
        return {**inputs, **{k: v.to(device) for k, v in grouping.items()}}

    def __call__(self, frame: Frame, kp3d: Keypoints3D) -> torch.Tensor:
        if len(kp3d) == 0:
            return torch.zeros(0, self.conf["descriptor_dim"], device=self.device)
        return super().__call__(frame, kp3d)

    def forward(self, inputs: dict[str, torch.Tensor]) -> torch.Tensor:
        """a batch of `prepare`d frames (xyz [B x N x 3], reflectance [B x N x 1], key_xyz [B x M x 3],
        key_reflectance [B x M x 1] and the grouping indices) -> keypoint descriptors [B x M x D], [local | global].

        Rows past a frame's own counts are padding, never gathered by its indices; the nodes are the same number in
        every frame, so the global max sees no padding."""
        g = inputs
        xyz1, f1 = self.sa1(g["xyz"], g["reflectance"], g["fps1"], g["ball1"])
        xyz2, f2 = self.sa2(xyz1, f1, g["fps2"], g["ball2"])
        nodes = torch.cat([xyz2, f2], -1).transpose(1, 2)[..., None]  # [B x C x S2 x 1]
        glob = self.global_mlp(nodes)[..., 0].amax(-1)  # [B x G]
        up = torch.cat([interpolate(xyz1, xyz2, f2, g["up"]), f1], -1)
        f1 = self.fp(up.transpose(1, 2)[..., None])[..., 0].transpose(1, 2)
        kxyz, nearest = g["key_xyz"], g["edge"]
        offsets = (kxyz[:, :, None] - gather(xyz1, nearest)) / self.conf["sa1"]["radius"]  # [B x M x 3 x 3]
        local = torch.cat([interpolate(kxyz, xyz1, f1, nearest), kxyz, g["key_reflectance"], offsets.flatten(2)], -1)
        real = torch.arange(kxyz.shape[1], device=kxyz.device)[None] < g["num_keys"].reshape(-1, 1)  # [B x M]
        local = self.head(local, real)
        if self.conf["normalize_descriptors"]:
            local = F.normalize(local, dim=-1)
        return torch.cat([local, glob[:, None].expand(-1, local.shape[1], -1)], -1)
