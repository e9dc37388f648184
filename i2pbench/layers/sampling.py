"""SuperPoint-style descriptor sampling: a stride-s descriptor map read bilinearly at pixels, and the per-image
normalisation of a padded batch of images.

Coordinate mapping: pixel centres sit at integer (u, v) (the convention of `Keypoints2D`). Descriptor cell (i, j) of a
stride-s map pools pixels [s j, s j + s) x [s i, s i + s), so its centre is at u = s j + (s - 1) / 2; a pixel lies at
cell coordinate x = (u - (s - 1) / 2) / s, which `grid_sample(align_corners=True)` reads at 2x / (Wc - 1) - 1; pixels
beyond the outer cell centres take the border cell's value. EdgeRegNet's image encoder brought them; CorrI2P's and
DeepI2P's image branches read their maps the same way.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)


def pixel_to_grid(uv: torch.Tensor, size: tuple[int, int], stride: float) -> torch.Tensor:
    """pixel coordinates [... x 2] -> grid_sample coordinates [... x 2] on a (Wc, Hc) map (align_corners=True)."""
    cells = (uv - (stride - 1) / 2) / stride
    extent = torch.tensor([max(size[0] - 1, 1), max(size[1] - 1, 1)], device=uv.device, dtype=uv.dtype)
    return cells / extent * 2 - 1


def sample_descriptors(fmap: torch.Tensor, uv: torch.Tensor, stride: float) -> torch.Tensor:
    """bilinear lookup of fmap [B x D x Hc x Wc] at pixels uv [B x M x 2] -> [B x M x D]."""
    grid = pixel_to_grid(uv, (fmap.shape[-1], fmap.shape[-2]), stride)
    out = F.grid_sample(fmap, grid[:, None], mode="bilinear", padding_mode="border", align_corners=True)
    return out[:, :, 0].transpose(1, 2)


def normalize_images(grey: torch.Tensor, size: torch.Tensor) -> torch.Tensor:
    """zero mean, unit std (unbiased) per image over its own [H x W] of a padded batch [B x 1 x H' x W']; padding 0."""
    rows = torch.arange(grey.shape[-2], device=grey.device)
    cols = torch.arange(grey.shape[-1], device=grey.device)
    valid = (rows[None, :, None] < size[:, :1, None]) & (cols[None, None, :] < size[:, 1:, None])
    valid = valid[:, None].to(grey.dtype)
    count = valid.sum((1, 2, 3), keepdim=True)
    mean = (grey * valid).sum((1, 2, 3), keepdim=True) / count
    var = ((grey - mean) ** 2 * valid).sum((1, 2, 3), keepdim=True) / (count - 1).clamp(min=1)
    return (grey - mean) / var.sqrt().clamp(min=1e-3) * valid
