"""VP2P-Match's voxel branch: SPVCNN (SPVNAS's semantic-KITTI network, cr 0.5, 0.05 m voxels, 128 outputs per point)
on i2pbench.layers.sparse, computing what the authors' `SPVCNN` computes on torchsparse 2.0.

A sparse U-Net over the voxels (a 3^3 stem, four stages that halve the grid with a 2^3 stride-2 convolution and two
residual blocks, four that double it back with a transposed 2^3 convolution, the skip concatenated after it, and two
residual blocks) with a point branch beside it: the points read the voxels trilinearly after the stem, the bottom
and the middle of the U and at the end, each time adding an MLP of their previous features, and are averaged back
into the voxels before the decoder's halves. Module names and shapes are the authors' (`stem.0.kernel`,
`stage1.1.net.0.kernel`, `up1.1.0.downsample.0.kernel`, `point_transforms.0.0.weight`, ...).
"""

from __future__ import annotations

import torch
from torch import nn

from i2pbench.layers.point_voxel import SparsePoints, initial_voxelize, point_to_voxel, voxel_to_point
from i2pbench.layers.sparse import SparseBatchNorm, SparseConv3d, SparseReLU, SparseVoxels, sparse_cat

VOXEL_SIZE = 0.05  # metres
WIDTHS = (32, 32, 64, 128, 256, 256, 128, 96, 96)  # SPVCNN's channels at cr 1


def conv_block(c_in: int, c_out: int, size: int, stride: int = 1, transposed: bool = False) -> nn.Sequential:
    """convolution, BatchNorm, ReLU (the authors' Basic(De)ConvolutionBlock's `net`)."""
    return nn.Sequential(
        SparseConv3d(c_in, c_out, size, stride, transposed=transposed), SparseBatchNorm(c_out), SparseReLU()
    )


class BasicBlock(nn.Module):
    """one convolution block, kept under `net` as the authors' state dict names it."""

    def __init__(self, c_in: int, c_out: int, size: int, stride: int = 1, transposed: bool = False) -> None:
        super().__init__()
        self.net = conv_block(c_in, c_out, size, stride, transposed)

    def forward(self, x: SparseVoxels) -> SparseVoxels:
        return self.net(x)


class ResidualBlock(nn.Module):
    """two 3^3 convolutions beside a shortcut (a 1^3 convolution and BatchNorm where the width changes)."""

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.net = nn.Sequential(*conv_block(c_in, c_out, 3), SparseConv3d(c_out, c_out, 3), SparseBatchNorm(c_out))
        self.downsample = (
            nn.Identity() if c_in == c_out else nn.Sequential(SparseConv3d(c_in, c_out, 1), SparseBatchNorm(c_out))
        )
        self.relu = SparseReLU()

    def forward(self, x: SparseVoxels) -> SparseVoxels:
        out = self.net(x)
        return self.relu(out.with_feats(out.feats + self.downsample(x).feats))


def encoder_stage(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(BasicBlock(c_in, c_in, 2, 2), ResidualBlock(c_in, c_out), ResidualBlock(c_out, c_out))


def decoder_stage(c_in: int, c_out: int, c_skip: int) -> nn.ModuleList:
    return nn.ModuleList(
        [
            BasicBlock(c_in, c_out, 2, 2, transposed=True),
            nn.Sequential(ResidualBlock(c_out + c_skip, c_out), ResidualBlock(c_out, c_out)),
        ]
    )


def point_mlp(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(c_in, c_out), nn.BatchNorm1d(c_out), nn.ReLU())


def voxel_coordinates(pc: torch.Tensor) -> torch.Tensor:
    """[B x 3 x N] points in metres -> [B N x 4] (x, y, z, batch) float voxel coordinates, as the authors' network
    makes them: each cloud moved to its smallest corner, divided by the voxel size and rounded."""
    xyz = pc.transpose(2, 1)
    cells = torch.round((xyz - xyz.min(dim=1, keepdim=True).values).reshape(-1, 3) / VOXEL_SIZE)
    batch = torch.arange(pc.shape[0], device=pc.device).repeat_interleave(pc.shape[2]).unsqueeze(1)
    return torch.cat([cells, batch.to(cells.dtype)], dim=1)


class SPVCNN(nn.Module):
    """[B N x C_in] point features at [B N x 4] voxel coordinates -> global [B x classes], per point
    [B x classes x N]."""

    def __init__(self, in_channels: int = 7, classes: int = 128, cr: float = 0.5, dropout: float = 0.3) -> None:
        super().__init__()
        cs = [int(cr * w) for w in WIDTHS]
        self.stem = nn.Sequential(*conv_block(in_channels, cs[0], 3), *conv_block(cs[0], cs[0], 3))
        self.stage1, self.stage2 = encoder_stage(cs[0], cs[1]), encoder_stage(cs[1], cs[2])
        self.stage3, self.stage4 = encoder_stage(cs[2], cs[3]), encoder_stage(cs[3], cs[4])
        self.up1, self.up2 = decoder_stage(cs[4], cs[5], cs[3]), decoder_stage(cs[5], cs[6], cs[2])
        self.up3, self.up4 = decoder_stage(cs[6], cs[7], cs[1]), decoder_stage(cs[7], cs[8], cs[0])
        self.classifier = nn.Sequential(nn.Linear(cs[8], classes))
        self.point_transforms = nn.ModuleList(
            [point_mlp(cs[0], cs[4]), point_mlp(cs[4], cs[6]), point_mlp(cs[6], cs[8])]
        )
        self.dropout = nn.Dropout(dropout)
        self.classes = classes

    def forward(self, feats: torch.Tensor, coords: torch.Tensor, batch_size: int) -> tuple[torch.Tensor, torch.Tensor]:
        trace = self.trace(feats, coords)
        pointwise = trace["pointwise"].reshape(batch_size, -1, self.classes).transpose(2, 1)
        return pointwise.max(dim=-1).values, pointwise

    def trace(self, feats: torch.Tensor, coords: torch.Tensor) -> dict[str, torch.Tensor]:
        """every intermediate the reference vectors record: the voxel features after the stem (`x0`), the encoder
        (`x4`) and each decoder half (`y2`, `y4`), each trilinear read before its MLP is added (`devox0`-`devox3`),
        and the per-point outputs."""
        z, x0 = initial_voxelize(SparsePoints(feats, coords), VOXEL_SIZE, VOXEL_SIZE)
        x0 = self.stem(x0)
        z0 = voxel_to_point(x0, z)
        x1 = self.stage1(point_to_voxel(x0, z0))
        x2 = self.stage2(x1)
        x3 = self.stage3(x2)
        x4 = self.stage4(x3)
        devox1 = voxel_to_point(x4, z0).feats
        z1 = z0.with_feats(devox1 + self.point_transforms[0](z0.feats))
        y2 = self._decode(self._decode(self._revoxel(x4, z1), self.up1, x3), self.up2, x2)
        devox2 = voxel_to_point(y2, z1).feats
        z2 = z1.with_feats(devox2 + self.point_transforms[1](z1.feats))
        y4 = self._decode(self._decode(self._revoxel(y2, z2), self.up3, x1), self.up4, x0)
        devox3 = voxel_to_point(y4, z2).feats
        z3 = devox3 + self.point_transforms[2](z2.feats)
        return {
            "x0": x0.feats, "x4": x4.feats, "y2": y2.feats, "y4": y4.feats, "devox0": z0.feats,
            "devox1": devox1, "devox2": devox2, "devox3": devox3, "pointwise": self.classifier(z3),
        }  # fmt: skip

    def _revoxel(self, voxels: SparseVoxels, points: SparsePoints) -> SparseVoxels:
        y = point_to_voxel(voxels, points)
        return y.with_feats(self.dropout(y.feats))

    @staticmethod
    def _decode(x: SparseVoxels, stage: nn.ModuleList, skip: SparseVoxels) -> SparseVoxels:
        return stage[1](sparse_cat([stage[0](x), skip]))
