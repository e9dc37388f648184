"""Point <-> voxel conversions of SPVCNN (SPVNAS's `models/utils.py`, as VP2P-Match uses them) on `layers.sparse`.

Why: SPVCNN keeps a point branch beside its sparse voxel network: points are averaged into voxels, and voxel features
are read back at each point by trilinear interpolation of the 8 voxels around it. These follow torchsparse 2.0's
`spvoxelize`, `spcount`, `calc_ti_weights` and `spdevoxelize` so the same points give the same voxels, in the same
order (the first voxelisation orders voxels by torchsparse's coordinate hash, as its `torch.unique` of the hashes
does), and the same features. The point-to-voxel links of each stride depend only on the coordinates, so they are
computed once per stride and shared by every point tensor of one forward pass.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from i2pbench.layers.sparse import SparseVoxels, find_rows, kernel_offsets, voxel_hash

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)


@dataclass
class PointLinks:
    """per stride: each point's voxel row (`voxel_rows`, -1 if none) and the voxels' point counts, for averaging;
    each point's 8 surrounding voxel rows and their trilinear weights, for interpolation."""

    voxel_rows: dict[int, tuple[torch.Tensor, torch.Tensor]] = field(default_factory=dict)
    corners: dict[int, tuple[torch.Tensor, torch.Tensor]] = field(default_factory=dict)


@dataclass
class SparsePoints:
    """per-point features `feats` [N x C] at float coordinates `coords` [N x 4] (x, y, z in finest-voxel units,
    batch), with the links to voxels shared by every point tensor derived from them."""

    feats: torch.Tensor
    coords: torch.Tensor
    links: PointLinks = field(default_factory=PointLinks)

    def with_feats(self, feats: torch.Tensor) -> SparsePoints:
        return SparsePoints(feats, self.coords, self.links)


def average_into(feats: torch.Tensor, rows: torch.Tensor, counts: torch.Tensor) -> torch.Tensor:
    """[N x C] point features -> [V x C] per-voxel means (`spvoxelize`: each point adds feats / count)."""
    kept = rows >= 0
    rows, feats = rows[kept], feats[kept]
    share = feats / counts[rows].unsqueeze(1).to(feats.dtype)
    return feats.new_zeros(len(counts), feats.shape[1]).index_add(0, rows, share)


def voxel_counts(rows: torch.Tensor, n_voxels: int) -> torch.Tensor:
    """how many points each voxel holds (`spcount`; rows of -1 count nowhere)."""
    return torch.bincount(rows[rows >= 0], minlength=n_voxels).to(torch.int32)


def initial_voxelize(points: SparsePoints, point_res: float, voxel_res: float) -> tuple[SparsePoints, SparseVoxels]:
    """points at `point_res` units -> (the points rescaled to `voxel_res` voxels, their mean features per voxel).

    Voxels are ordered by their coordinate hash, as torchsparse's `torch.unique(hashes)` orders them."""
    scaled = torch.cat([points.coords[:, :3] * point_res / voxel_res, points.coords[:, 3:]], dim=1)
    cells = torch.floor(scaled).to(torch.int32)
    table, rows = torch.unique(voxel_hash(cells), return_inverse=True)
    counts = voxel_counts(rows, len(table))
    coords = torch.zeros(len(table), 4, dtype=torch.int32, device=cells.device).index_copy(0, rows, cells)
    moved = SparsePoints(points.feats, scaled, points.links)
    moved.links.voxel_rows[1] = (rows, counts)
    return moved, SparseVoxels(average_into(points.feats, rows, counts), coords, 1)


def _cells(coords: torch.Tensor, stride: int) -> torch.Tensor:
    """each point's voxel at `stride`: floor(xyz / stride) * stride, with the batch (SPVNAS's point_to_voxel)."""
    xyz = torch.floor(coords[:, :3] / stride).to(torch.int32) * stride
    return torch.cat([xyz, coords[:, 3:].to(torch.int32)], dim=1)


def point_to_voxel(voxels: SparseVoxels, points: SparsePoints) -> SparseVoxels:
    """the mean of the points' features in each of `voxels`' voxels, on `voxels`' coordinates and maps."""
    stride = voxels.stride
    if stride not in points.links.voxel_rows:
        rows = find_rows(_cells(points.coords, stride), voxels.coords)
        points.links.voxel_rows[stride] = (rows, voxel_counts(rows, len(voxels.coords)))
    rows, counts = points.links.voxel_rows[stride]
    return voxels.with_feats(average_into(points.feats, rows, counts))


def trilinear_weights(coords: torch.Tensor, rows: torch.Tensor, stride: int) -> torch.Tensor:
    """[N x 4] point coordinates, [8 x N] corner rows -> [8 x N] weights (`calc_ti_weights`): each corner's
    trilinear weight, 0 at absent corners, renormalised to sum to 1 (plus torchsparse's 1e-8)."""
    p = coords[:, :3]
    low = torch.floor(p / stride) * stride
    high = low + stride
    to_low, to_high = p - low, high - p  # corner bit 0 takes (high - p), bit 1 takes (p - low)
    weights = []
    for bits in range(8):  # x slowest, z fastest: kernel_offsets(2)'s order
        w = torch.ones_like(p[:, 0])
        for axis, bit in enumerate(((bits >> 2) & 1, (bits >> 1) & 1, bits & 1)):
            w = w * (to_low[:, axis] if bit else to_high[:, axis])
        weights.append(w)
    w = torch.stack(weights) / stride**3
    w = torch.where(rows == -1, torch.zeros_like(w), w)
    return w / (w.sum(dim=0) + 1e-8)


def voxel_to_point(voxels: SparseVoxels, points: SparsePoints) -> SparsePoints:
    """each point's trilinear interpolation of the 8 voxels around it at `voxels`' stride (`spdevoxelize`)."""
    stride = voxels.stride
    if stride not in points.links.corners:
        offsets = kernel_offsets(2, stride, points.coords.device)
        cells = _cells(points.coords, stride).unsqueeze(0).repeat(8, 1, 1)
        cells[..., :3] += offsets.unsqueeze(1)
        rows = find_rows(cells, voxels.coords)
        with torch.no_grad():
            weights = trilinear_weights(points.coords, rows, stride)
        points.links.corners[stride] = (rows, weights)
    rows, weights = points.links.corners[stride]
    out = voxels.feats.new_zeros(len(points.coords), voxels.feats.shape[1])
    for k in range(8):
        out = out + weights[k].unsqueeze(1) * voxels.feats[rows[k].clamp(min=0)]
    return points.with_feats(out)
