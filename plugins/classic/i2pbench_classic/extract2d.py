"""Image keypoints: edge pixels from LSD (the paper's choice), Canny and Sobel (its ablations), random pixels, and a
regular grid (the dense pixels of CorrI2P's feature map, DeepI2P's grid cells).

Every extractor works on the grayscale image, returns pixel centres as float32 (u = column, v = row) in raster order,
and caps the count with the seeded rule in `capping` (uniform subset without replacement, sorted), so it is
deterministic per (seed, dataset, frame id).
"""

from __future__ import annotations

from typing import Any, ClassVar

import cv2
import numpy as np

from i2pbench.api import Extractor2D, Frame, Keypoints2D

from .capping import cap

CAP_CONF: dict[str, Any] = {
    "max_keypoints": 3000,  # keep at most this many (seeded uniform subset); None keeps every edge pixel
    "seed": 0,  # seeds the subset together with the dataset and frame id
}


def grayscale(image: np.ndarray) -> np.ndarray:
    """[H x W] uint8 luminance of an RGB image (what the paper's detectors run on)."""
    return cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)


def rasterise_segments(segments: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """[H x W] bool mask of the pixels on [K x 4] segments (x1, y1, x2, y2), pixel centres at integer coordinates.

    Each segment is sampled at steps of at most one pixel along its major axis (a DDA line, 8-connected) and every
    sample is rounded to the nearest pixel; samples outside the image are dropped. Vectorised over all segments.
    """
    width, height = size
    mask = np.zeros((height, width), dtype=bool)
    if len(segments) == 0:
        return mask
    x1, y1, x2, y2 = (segments[:, i].astype(np.float64) for i in range(4))
    steps = np.ceil(np.maximum(np.abs(x2 - x1), np.abs(y2 - y1))).astype(np.int64)
    counts = steps + 1
    seg = np.repeat(np.arange(len(segments)), counts)
    k = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    t = k / np.maximum(steps, 1)[seg]
    u = np.floor(x1[seg] + t * (x2 - x1)[seg] + 0.5).astype(np.int64)
    v = np.floor(y1[seg] + t * (y2 - y1)[seg] + 0.5).astype(np.int64)
    inside = (u >= 0) & (u < width) & (v >= 0) & (v < height)
    mask[v[inside], u[inside]] = True
    return mask


def mask_points(mask: np.ndarray) -> np.ndarray:
    """[N x 2] int32 (u, v) = (column, row) of a [H x W] mask's non-zero pixels in raster order (np.nonzero's order);
    OpenCV's findNonZero reads a uint8 (or bool) mask 3-4x faster than np.nonzero on the 2D array."""
    mask = np.ascontiguousarray(mask)
    points = cv2.findNonZero(mask.view(np.uint8) if mask.dtype == bool else mask.astype(np.uint8, copy=False))
    return np.zeros((0, 2), np.int32) if points is None else points.reshape(-1, 2)


def edge_pixels(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of a [H x W] mask's non-zero pixels in raster order, as np.nonzero gives them."""
    points = mask_points(mask)
    if points.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return points[:, 1], points[:, 0]


def points_to_keypoints(points: np.ndarray, frame: Frame, conf: dict[str, Any]) -> Keypoints2D:
    """Cap candidate pixels ([N x 2] (u, v), raster order) with the seeded rule and pack them as float32 (u, v):
    findNonZero's rows are already (u, v), so the kept ones are one row gather and one cast."""
    keep = cap(len(points), conf["max_keypoints"], conf["seed"], frame)
    return Keypoints2D(uv=np.take(points, keep, axis=0).astype(np.float32))


class EdgeExtractor2D(Extractor2D):
    """An extractor defined by an edge mask of the grayscale image (bool, or uint8 with edges non-zero)."""

    default_conf: ClassVar[dict[str, Any]] = dict(CAP_CONF)

    def edge_mask(self, gray: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def __call__(self, frame: Frame) -> Keypoints2D:
        return points_to_keypoints(mask_points(self.edge_mask(grayscale(frame.image))), frame, self.conf)


class LSDExtractor(EdgeExtractor2D):
    """Every pixel on every LSD segment (OpenCV's detector, default parameters, as the paper: no threshold tuning)."""

    name = "lsd"

    def edge_mask(self, gray: np.ndarray) -> np.ndarray:
        lines = cv2.createLineSegmentDetector().detect(gray)[0]
        segments = np.zeros((0, 4)) if lines is None else lines.reshape(-1, 4)
        return rasterise_segments(segments, (gray.shape[1], gray.shape[0]))


class CannyExtractor(EdgeExtractor2D):
    """Canny edge pixels with the paper's thresholds (50, 150)."""

    name = "canny"
    default_conf: ClassVar[dict[str, Any]] = {
        **CAP_CONF,
        "low": 50,  # hysteresis thresholds on the gradient magnitude
        "high": 150,
    }

    def edge_mask(self, gray: np.ndarray) -> np.ndarray:
        return cv2.Canny(gray, self.conf["low"], self.conf["high"])  # 0 or 255


class SobelExtractor(EdgeExtractor2D):
    """Pixels whose 3x3 Sobel gradient magnitude sqrt(dx^2 + dy^2) exceeds 150 (the paper's Sobel ablation)."""

    name = "sobel"
    default_conf: ClassVar[dict[str, Any]] = {
        **CAP_CONF,
        "threshold": 150.0,  # on the gradient magnitude of the uint8 grayscale image
        "ksize": 3,  # Sobel aperture
    }

    def edge_mask(self, gray: np.ndarray) -> np.ndarray:
        dx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=self.conf["ksize"])
        dy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=self.conf["ksize"])
        return cv2.magnitude(dx, dy) > self.conf["threshold"]


class RandomExtractor2D(Extractor2D):
    """max_keypoints pixels drawn uniformly without replacement: the no-edge baseline (same seeded rule as the cap)."""

    name = "random"
    default_conf: ClassVar[dict[str, Any]] = dict(CAP_CONF)

    def __call__(self, frame: Frame) -> Keypoints2D:
        width, height = frame.image_size
        rows, cols = np.divmod(cap(width * height, self.conf["max_keypoints"], self.conf["seed"], frame), width)
        uv = np.empty((rows.size, 2), dtype=np.float32)  # filled column by column: no [M x 2] int64 stack to cast
        uv[:, 0] = cols
        uv[:, 1] = rows
        return Keypoints2D(uv=uv)


class GridExtractor2D(Extractor2D):
    """The centres of the image's whole `stride` x `stride` cells, in raster order: the dense pixel set of methods
    that describe every cell of a strided feature map (CorrI2P's stride-8 map of a full-size KITTI image).

    Cell (i, j) covers pixels [stride j, stride j + stride) x [stride i, stride i + stride), whose centre is at
    u = stride j + (stride - 1) / 2 (pixel centres at integers). Partial cells at the right and bottom borders are left
    out, so an image narrower than one cell has none. The cap is the seeded rule of the other extractors.
    """

    name = "grid"
    default_conf: ClassVar[dict[str, Any]] = {
        "stride": 8,  # cell size in pixels
        "max_keypoints": None,  # keep at most this many cells (seeded uniform subset); None keeps the whole grid
        "seed": 0,  # seeds the subset together with the dataset and frame id
    }

    def __call__(self, frame: Frame) -> Keypoints2D:
        stride = int(self.conf["stride"])
        if stride < 1:
            raise ValueError(f"extractor2d 'grid': stride must be a positive number of pixels, got {stride}")
        width, height = frame.image_size
        rows, cols = np.divmod(np.arange((height // stride) * (width // stride)), max(width // stride, 1))
        keep = cap(len(rows), self.conf["max_keypoints"], self.conf["seed"], frame)
        centre = (stride - 1) / 2
        uv = np.stack([cols[keep] * stride + centre, rows[keep] * stride + centre], axis=1)
        return Keypoints2D(uv=uv.astype(np.float32).reshape(-1, 2))
