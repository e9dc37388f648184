"""Where an image keypoint sits, as a network input: its pixel normalised by the image size, in Fourier features.

DeepI2P's networks give each image cell a slot of their own (an attention weight per stride-32 pixel, a logit per
grid cell), which ties them to one image size. Here a slot's weights are computed from its cell's position instead,
so the same network serves any image size and cell count: an MLP of these features stands for the paper's slot.
"""

from __future__ import annotations

import math

import numpy as np
import torch


def normalised_pixels(uv: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """[M x 2] float32 in [0, 1]: pixels [M x 2] of a (width, height) image, its extent [-0.5, W - 0.5) -> [0, 1)."""
    width, height = size
    return ((np.asarray(uv, np.float64).reshape(-1, 2) + 0.5) / [width, height]).astype(np.float32)


def fourier_features(xy: torch.Tensor, frequencies: int) -> torch.Tensor:
    """[... x 2] positions in [0, 1] -> [... x (2 + 4 F)]: themselves, and sin, cos of 2^k pi x for k < F."""
    scales = math.pi * 2.0 ** torch.arange(frequencies, device=xy.device, dtype=xy.dtype)
    angles = (xy[..., None] * scales).flatten(-2)  # [... x 2F]
    return torch.cat([xy, angles.sin(), angles.cos()], -1)


def feature_width(frequencies: int) -> int:
    return 2 + 4 * frequencies
