"""CPU stand-ins for the `pointnet2_ops` calls of VP2P-Match's point branch (the package is CUDA only), written from
its CUDA kernels (pointnet2_ops_lib/pointnet2_ops/_ext-src/src/*_gpu.cu) in plain torch, forward only:
- `furthest_point_sample`: from index 0, each step the point of largest distance to the chosen set (squared, float32),
  skipping points within 1e-3 of the origin as sampling_gpu.cu does (`mag <= 1e-3`); ties: the first;
- `ball_query`: the first `nsample` points in index order with squared distance strictly below radius^2, padded with
  the first; 0 where none;
- `three_nn`: the 3 smallest squared distances (ties: the lower index, as the kernel's strict `<`), returned as
  distances (the wrapper's sqrt); with fewer than 3 known points, index 0 at distance inf in the unfilled slots;
- `gather_operation`, `grouping_operation`, `three_interpolate`: indexing and a weighted sum.
`install()` puts them in `sys.modules` as `pointnet2_ops.pointnet2_utils` before the authors' modules import it.
"""

from __future__ import annotations

import sys
import types

import torch


def furthest_point_sample(xyz: torch.Tensor, npoint: int) -> torch.Tensor:
    batch, n, _ = xyz.shape
    out = torch.zeros(batch, npoint, dtype=torch.int32)
    for b in range(batch):
        p = xyz[b]
        eligible = p.square().sum(-1) > 1e-3
        dist = torch.full((n,), 1e10)
        far = 0
        for i in range(npoint):
            out[b, i] = far
            d = (p[:, 0] - p[far, 0]) ** 2 + (p[:, 1] - p[far, 1]) ** 2 + (p[:, 2] - p[far, 2]) ** 2
            dist = torch.where(eligible, torch.minimum(dist, d), dist)
            far = int(torch.argmax(torch.where(eligible, dist, torch.full_like(dist, -1.0))))
    return out


def gather_operation(features: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    return torch.stack([f[:, i.long()] for f, i in zip(features, idx, strict=True)])


def grouping_operation(features: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    return torch.stack([f[:, i.long()] for f, i in zip(features, idx, strict=True)])


def ball_query(radius: float, nsample: int, xyz: torch.Tensor, new_xyz: torch.Tensor) -> torch.Tensor:
    out = torch.zeros(*new_xyz.shape[:2], nsample, dtype=torch.int32)
    for b in range(len(xyz)):
        d2 = ((new_xyz[b, :, None, :] - xyz[b, None, :, :]) ** 2).sum(-1)
        for j, inside in enumerate(d2 < radius * radius):
            found = inside.nonzero().squeeze(1)[:nsample]
            if len(found):
                out[b, j] = found[0]
                out[b, j, : len(found)] = found
    return out


def three_nn(unknown: torch.Tensor, known: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """with fewer than 3 known points the kernel's unfilled slots keep index 0 and its 1e40 start, inf as a float."""
    d2 = ((unknown[:, :, None, :] - known[:, None, :, :]) ** 2).sum(-1)
    missing = max(0, 3 - d2.shape[-1])
    d2 = torch.cat([d2, d2.new_full((*d2.shape[:2], missing), float("inf"))], dim=-1)
    values, order = torch.sort(d2, dim=-1, stable=True)
    order = torch.where(order >= known.shape[1], torch.zeros_like(order), order)
    return torch.sqrt(values[..., :3]), order[..., :3].to(torch.int32)


def three_interpolate(features: torch.Tensor, idx: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    picked = grouping_operation(features, idx)  # B x C x n x 3
    return (picked * weight.unsqueeze(1)).sum(-1)


def install() -> None:
    package, utils = types.ModuleType("pointnet2_ops"), types.ModuleType("pointnet2_ops.pointnet2_utils")
    names = ("furthest_point_sample", "gather_operation", "grouping_operation", "ball_query", "three_nn",
             "three_interpolate")  # fmt: skip
    for name in names:
        setattr(utils, name, globals()[name])
    utils.__all__ = list(names)
    package.pointnet2_utils = utils
    sys.modules["pointnet2_ops"], sys.modules["pointnet2_ops.pointnet2_utils"] = package, utils
