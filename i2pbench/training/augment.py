"""Training augmentations by name (`--augment photometric,lidar-dropout`), and the photometric one of images.

Photometric augmentation is domain randomisation against the gap between cameras and scenes. Applied after
extraction, so edge pixels stay where the clean image put them (the extractor outputs are cached per frame) and only
what the 2D encoder sees changes: exposure (gamma), contrast, brightness, sensor noise and defocus. Each sample draws
its own parameters from a generator seeded by (seed, sample index), so training stays a pure function of the seed.
It leaves the scan untouched; `lidar-dropout` thins the scan (lidar_dropout.py), never moving a point, so the ground
truth stays exact under both.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .lidar_dropout import LidarDropout

AUGMENTATIONS = ("none", "photometric", "lidar-dropout")


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


@dataclass(frozen=True)
class Augmentation:
    """what a `--augment` list turns on: an image augmentation and a scan one, each None when off."""

    image: Photometric | None = None
    lidar: LidarDropout | None = None


def augmentation_names(text: str) -> list[str]:
    """`"photometric, lidar-dropout"` -> the names, checked; "none" stands alone."""
    names = [part.strip() for part in text.split(",")]
    unknown = [n for n in names if n not in AUGMENTATIONS]
    if unknown:
        raise ValueError(f"augmentation {unknown[0]!r}: choose from {', '.join(AUGMENTATIONS)} (a comma list)")
    if "none" in names and len(names) > 1:
        raise ValueError(f"augmentation {text!r}: 'none' cannot be combined with others")
    return names


def augmentations(text: str) -> Augmentation:
    """the augmentations a `--augment` value names."""
    names = augmentation_names(text)
    return Augmentation(
        image=Photometric() if "photometric" in names else None,
        lidar=LidarDropout() if "lidar-dropout" in names else None,
    )
