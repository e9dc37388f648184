"""VP2P-Match's network (`VP2PMatchNet`, models/triplet_network.py): the three branches, their fusion and the heads.

The point and voxel branches' per-point features are added; each modality's per-element features are concatenated
with the other modality's global feature (the image's beside the cloud's and the reverse) for the overlap-score
heads (sigmoid), while the descriptors are the per-element features through three 1x1 convolutions, L2-normalised:
64-d for both pixels (at a quarter of the image's resolution) and points. State dict keys are the authors'
(`resnet.*`, `point_transformer.*`, `voxel_branch.*`, `pc_score_head.*`, `img_feature_layer.*`, ...).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from .image import ImageResNet
from .points import PointsEncoder
from .spvcnn import SPVCNN, voxel_coordinates


def score_head(c_in: int, dims: int) -> nn.Sequential:
    conv, norm = (nn.Conv1d, nn.BatchNorm1d) if dims == 1 else (nn.Conv2d, nn.BatchNorm2d)
    return nn.Sequential(
        conv(c_in, 128, 1, bias=False), norm(128), nn.ReLU(),
        conv(128, 64, 1, bias=False), norm(64), nn.ReLU(),
        conv(64, 1, 1, bias=False), nn.Sigmoid(),
    )  # fmt: skip


def feature_layer(c_in: int, c_out: int, dims: int) -> nn.Sequential:
    conv, norm = (nn.Conv1d, nn.BatchNorm1d) if dims == 1 else (nn.Conv2d, nn.BatchNorm2d)
    return nn.Sequential(
        conv(c_in, c_in, 1, bias=False), norm(c_in), nn.ReLU(),
        conv(c_in, c_in, 1, bias=False), norm(c_in), nn.ReLU(),
        conv(c_in, c_out, 1, bias=False),
    )  # fmt: skip


class VP2PMatchNet(nn.Module):
    """pc [B x 3 x N] metres, intensity [B x 1 x N], sn [B x 3 x N] normals, img [B x 3 x H x W] -> pixel descriptors
    [B x 64 x H/4 x W/4], point descriptors [B x 64 x N], pixel scores [B x 1 x H/4 x W/4], point scores [B x 1 x N]."""

    def __init__(self) -> None:
        super().__init__()
        self.point_transformer = PointsEncoder()
        self.voxel_branch = SPVCNN()
        self.resnet = ImageResNet()
        self.pc_score_head = score_head(128 + 512, dims=1)
        self.img_score_head = score_head(64 + 512, dims=2)
        self.img_feature_layer = feature_layer(64, 64, dims=2)
        self.pc_feature_layer = feature_layer(128, 64, dims=1)

    def forward(self, pc, intensity, sn, img) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        out = self.trace(pc, intensity, sn, img)
        return out["pixel_feat"], out["point_feat"], out["img_score"], out["pc_score"]

    def trace(self, pc, intensity, sn, img) -> dict[str, torch.Tensor]:
        cloud = torch.cat([pc, intensity, sn], dim=1)
        global_img, pixels = self.resnet(img)
        global_pc, points = self.point_transformer(cloud)
        voxel_in = cloud.transpose(2, 1).reshape(-1, cloud.shape[1])
        _, voxels = self.voxel_branch(voxel_in, voxel_coordinates(pc), pc.shape[0])
        points = points + voxels
        h, w = pixels.shape[2:]
        img_fusion = torch.cat([pixels, global_pc[:, :, None, None].expand(-1, -1, h, w)], dim=1)
        pc_fusion = torch.cat([points, global_img[:, :, None].expand(-1, -1, points.shape[2])], dim=1)
        return {
            "img_score": self.img_score_head(img_fusion),
            "pc_score": self.pc_score_head(pc_fusion),
            "pixel_feat": F.normalize(self.img_feature_layer(pixels), dim=1, p=2),
            "point_feat": F.normalize(self.pc_feature_layer(points), dim=1, p=2),
        }
