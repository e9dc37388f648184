"""Photometric augmentation of training images: domain randomisation against the gap between cameras and scenes.

Applied after extraction, so edge pixels stay where the clean image put them (the extractor outputs are cached per
frame) and only what the 2D encoder sees changes: exposure (gamma), contrast, brightness, sensor noise and defocus.
Each sample draws its own parameters from a generator seeded by (seed, sample index), so training stays a pure
function of the seed. The LiDAR scan is untouched: its geometry carries the ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

AUGMENTATIONS = ("none", "photometric")


@dataclass(frozen=True)
class Photometric:
    """ranges the parameters are drawn from, uniformly."""

    gamma: tuple[float, float] = (0.6, 1.5)  # out = in ** gamma on [0, 1]
    contrast: tuple[float, float] = (0.6, 1.5)  # about the image mean
    brightness: tuple[float, float] = (-30.0, 30.0)  # grey levels added
    noise_std: tuple[float, float] = (0.0, 8.0)  # grey levels, Gaussian per pixel and channel
    blur_probability: float = 0.3
    blur_sigma: tuple[float, float] = (0.5, 1.5)  # px, Gaussian

    def __call__(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """uint8 [H x W x 3] -> augmented uint8 [H x W x 3] (a new array)."""
        x = (image.astype(np.float32) / 255.0) ** rng.uniform(*self.gamma) * 255.0
        x = (x - x.mean()) * rng.uniform(*self.contrast) + x.mean() + rng.uniform(*self.brightness)
        x = x + rng.normal(0.0, rng.uniform(*self.noise_std), x.shape).astype(np.float32)
        if rng.random() < self.blur_probability:
            x = cv2.GaussianBlur(x, (0, 0), rng.uniform(*self.blur_sigma))
        return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def augmenter(name: str) -> Photometric | None:
    if name not in AUGMENTATIONS:
        raise ValueError(f"augmentation {name!r}: choose one of {', '.join(AUGMENTATIONS)}")
    return Photometric() if name == "photometric" else None
