"""Pixel positions for positional encoders: centred on the image and divided by a fraction of its longer side, the
normalisation SuperGlue's keypoint encoder uses (EdgeRegNet's exchangers; only the fraction differs between them)."""

from __future__ import annotations

import torch

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)


def centred_pixels(uv: torch.Tensor, size: tuple[int, int], span: float) -> torch.Tensor:
    """pixels [... x 2] on an image of size (W, H) -> (uv - centre) / (span * max(W, H)): span 0.5 puts the longer
    side on [-1, 1], SuperGlue's 0.7 inside it."""
    w, h = size
    return (uv - uv.new_tensor([w / 2, h / 2])) / (max(w, h) * span)
