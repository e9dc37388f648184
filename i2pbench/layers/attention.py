"""Attention masks for padded batches of keypoints (scaled dot-product attention's boolean `attn_mask`).

EdgeRegNet's exchangers brought it; CorrI2P's node attention uses it too.
"""

from __future__ import annotations

import torch

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)


def key_mask(mask: torch.Tensor | None) -> torch.Tensor | None:
    """SDPA's boolean mask [B x 1 x 1 x M] from keypoint masks [B x M]; a frame with no key attends to its padding
    (its outputs are padding too), so no row of softmax is empty."""
    if mask is None:
        return None
    return (mask | ~mask.any(-1, keepdim=True))[:, None, None, :]
