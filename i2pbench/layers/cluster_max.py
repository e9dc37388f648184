"""Per-cluster channel maxima of point features: the forward value of SO-Net's `index_max` CUDA kernel (DeepI2P's
and CorrI2P's point encoders), computed on any device by a scatter max.

The kernel returns, per node and channel, the index of the member point holding the largest value; the encoders only
gather with it, so the gathered value (the maximum itself) is what they compute, and a scatter max gives it exactly.
"""

from __future__ import annotations

import torch

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)


def cluster_max(features: torch.Tensor, cluster: torch.Tensor, clusters: int) -> torch.Tensor:
    """[B x C x N] features, [B x N] cluster index per point -> [B x C x clusters] channel maxima (0 if empty)."""
    index = cluster[:, None, :].expand_as(features)
    out = features.new_zeros(features.shape[0], features.shape[1], clusters)
    return out.scatter_reduce(2, index, features, "amax", include_self=False)
