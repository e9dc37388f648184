"""Keypoints pooled into nodes, and per-frame vectors over a padded batch of keypoints: the pieces of CorrI2P's
exchanger that DeepI2P's fusion reuses.
"""

from __future__ import annotations

import torch

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)


def pool_nodes(local: torch.Tensor, node: torch.Tensor, mask: torch.Tensor, count: int) -> tuple[torch.Tensor, ...]:
    """max of local [B x M x C] over each node's members (node [B x M] in [0, count), padding masked out)
    -> node features [B x count x C], and which nodes have a member [B x count]."""
    index = torch.where(mask, node, torch.full_like(node, count))  # padding goes to a dropped extra node
    feats = local.new_zeros(local.shape[0], count + 1, local.shape[2])
    feats = feats.scatter_reduce(1, index[..., None].expand(-1, -1, local.shape[2]), local, "amax", include_self=False)
    members = torch.zeros(local.shape[0], count + 1, device=local.device).scatter_add_(1, index, mask.float())
    return feats[:, :count], members[:, :count] > 0


def masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """mean of x [B x M x C] over the rows mask [B x M] keeps -> [B x C] (0 for a frame with none)."""
    weights = mask.to(x.dtype)[..., None]
    return (x * weights).sum(1) / weights.sum(1).clamp(min=1)


def expand(glob: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """a per-frame vector [B x G] repeated for each keypoint of like [B x M x C] -> [B x M x G]."""
    return glob[:, None].expand(-1, like.shape[1], -1)
