"""LiDAR keypoints: depth and reflectance discontinuities along each scan line (the paper's rule), and random points.

The paper (EdgeRegNet, "3D Edge Points Extraction"), with points i in scan order along one ring:
    dr_i = r_{i+1} - r_i;  if dr_i / r_i > eps_D select point i-1;  if dr_i / r_i < -eps_D select point i+1,
and the same for reflectance with dR_i = R_{i+1} - R_i against eps_R (an absolute difference, R is in [0, 1]).

Which side that picks. A rise (r_{i+1} much larger than r_i) means point i is the last return on a near object and
i+1 is on the background: i-1 is one more step back into the near object, so it is a near-side point, one sample in
from the boundary point i. A drop (r_{i+1} much smaller than r_i) means i+1 is the first return on a near object: it
is the near-side boundary point itself. So both cases select the foreground (nearer) side, which is what projects onto
the image's occluding contour; the rise case is offset by one sample (the paper says this avoids missing near
points because of the sensor's mechanical offsets). Taken literally the rule has one quirk we keep: on an object one
return wide (far, near, far at i-1, i, i+1) the drop selects i (near) and the rise selects i-1 (far).

Indexing details: differences are only taken between consecutive points of the same ring (Frame.ring, point order
kept within a ring), a selection is dropped when i-1 falls outside the ring, and a point with r_i = 0 (no return)
never triggers the relative depth test. Ranges are Frame.ranges (sensor distances, unchanged by the protocol).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from i2pbench.api import Extractor3D, Frame, Keypoints3D

from .capping import cap

CAP_CONF: dict[str, Any] = {
    "max_keypoints": 3000,  # keep at most this many (seeded uniform subset); None keeps every edge point
    "seed": 0,  # seeds the subset together with the dataset and frame id
}


def scan_order(ring: np.ndarray) -> np.ndarray | None:
    """Point indices grouped by ring, keeping the scan order within each ring (a stable sort); None when the points
    are grouped already (every KITTI and nuScenes scan), so no copy is made."""
    ring = np.asarray(ring)
    if ring.size < 2 or not (ring[1:] < ring[:-1]).any():
        return None
    return np.argsort(ring, kind="stable").astype(np.int64)


def select_discontinuities(
    delta: np.ndarray, same_ring: np.ndarray, threshold: float, out: np.ndarray | None = None
) -> np.ndarray:
    """[n] bool over scan-order positions, selected by the paper's rule, given delta[i] (the change from i to i+1)
    for i < n - 1; `out` (when given) is or-ed into, so several rules mark one mask without index lists.

    `same_ring[i]` says points i and i+1 lie on the same ring. A rise at i selects i-1 (when it is on the ring too),
    a drop at i selects i+1. NaN deltas (no return on either side) select nothing.
    """
    out = np.zeros(delta.size + 1, dtype=bool) if out is None else out
    drop = delta < -threshold
    drop &= same_ring
    out[1:] |= drop
    rise = delta[1:] > threshold
    rise &= same_ring[1:]
    rise &= same_ring[:-1]  # i - 1 for every rise at i >= 1, on the ring too
    out[:-2] |= rise
    return out


def relative_change(values: np.ndarray) -> np.ndarray:
    """(v_{i+1} - v_i) / v_i, NaN where v_i = 0 (no return: never a relative jump)."""
    base = values[:-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        change = np.diff(values) / base
    change[base <= 0] = np.nan
    return change


def normalised_reflectance(points: np.ndarray) -> np.ndarray:
    """Reflectance in [0, 1]: the frame contract already says so; a sensor that reports a larger scale is divided by
    its maximum so eps_R keeps its meaning."""
    refl = points[:, 3].astype(np.float64)
    top = float(refl.max()) if refl.size else 0.0
    return refl / top if top > 1.0 else np.clip(refl, 0.0, 1.0)


def all_finite(values: np.ndarray) -> bool:
    """Whether every value is finite. Their float sum is finite only then (a NaN or an infinity stays non-finite
    through any sum), and einsum's sum reads a float32 array ~1.3x faster than isfinite(values).all(); a sum that
    overflows on finite values is settled by the plain test."""
    flat = values.reshape(-1)
    return bool(np.isfinite(np.einsum("i->", flat))) or bool(np.isfinite(flat).all())


_ROW_OF_BYTES = {1: np.uint8, 2: np.uint16, 4: np.uint32, 8: np.uint64}


def finite_rows(values: np.ndarray) -> np.ndarray:
    """[N] bool: rows of [N x C] with every value finite. For C of 1, 2, 4 or 8 a row of isfinite's bools is read as
    one unsigned integer whose bytes must all be 1: 30x faster than .all(axis=1) over 4 columns, same answer."""
    finite = np.isfinite(values)
    width = _ROW_OF_BYTES.get(finite.shape[1]) if finite.ndim == 2 and finite.flags.c_contiguous else None
    if width is None:
        return finite.all(axis=1)
    ones = int.from_bytes(b"\x01" * finite.shape[1], "little")
    return finite.view(width)[:, 0] == ones


class ScanLines:
    """A frame's points in scan order (grouped by ring, order kept within a ring) and one mask of selected points,
    which every rule marks: a union of rules then needs no index lists, sorting or dedup."""

    def __init__(self, frame: Frame) -> None:
        self.frame = frame
        self.order = scan_order(frame.ring)
        ring = self.ordered(np.asarray(frame.ring))
        self.same_ring = ring[1:] == ring[:-1]
        self.mask = np.zeros(ring.size, dtype=bool)

    def ordered(self, values: np.ndarray) -> np.ndarray:
        return values if self.order is None else values[self.order]

    def mark_depth(self, eps_depth: float) -> None:
        """Depth-discontinuous points: relative range change beyond eps_D (ranges as the sensor measured them)."""
        change = relative_change(self.ordered(self.frame.ranges.astype(np.float64)))
        select_discontinuities(change, self.same_ring, eps_depth, self.mask)

    def mark_reflectance(self, eps_reflectance: float) -> None:
        """Reflectance-discontinuous points: absolute reflectance change beyond eps_R."""
        change = np.diff(self.ordered(normalised_reflectance(self.frame.points)))
        select_discontinuities(change, self.same_ring, eps_reflectance, self.mask)

    def marked(self) -> np.ndarray:
        """Point indices of the marked points, distinct and sorted."""
        positions = np.flatnonzero(self.mask)
        return positions if self.order is None else np.sort(self.order[positions])


def depth_edges(frame: Frame, eps_depth: float) -> np.ndarray:
    """Depth-discontinuous point indices, distinct and sorted."""
    lines = ScanLines(frame)
    lines.mark_depth(eps_depth)
    return lines.marked()


def reflectance_edges(frame: Frame, eps_reflectance: float) -> np.ndarray:
    """Reflectance-discontinuous point indices, distinct and sorted."""
    lines = ScanLines(frame)
    lines.mark_reflectance(eps_reflectance)
    return lines.marked()


def keypoints(index: np.ndarray, rows: np.ndarray) -> Keypoints3D:
    """Keypoints3D.from_index(frame, index) given rows = frame.points[index]: xyz is filled one column at a time,
    3x faster than copying the [M x 3] block out of the [M x 4] rows in one go; the same arrays."""
    xyz = np.empty((rows.shape[0], 3), dtype=rows.dtype)
    for column in range(3):
        xyz[:, column] = rows[:, column]
    return Keypoints3D(index=index.astype(np.int64, copy=False), xyz=xyz, reflectance=np.ascontiguousarray(rows[:, 3]))


class EdgeExtractor3D(Extractor3D):
    """An extractor defined by a set of candidate point indices, capped with the seeded rule."""

    default_conf: ClassVar[dict[str, Any]] = dict(CAP_CONF)

    def candidates(self, frame: Frame) -> np.ndarray:
        """Candidate point indices, distinct and sorted."""
        raise NotImplementedError

    def finite_candidates(self, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        """The candidates whose point is finite (a corrupt return is never a keypoint), and their rows of points."""
        index = self.candidates(frame)
        rows = np.take(frame.points, index, axis=0)  # take: ~10x a fancy index on [N x 4]
        if np.isfinite(rows).all():  # the usual case: no row mask to build and apply
            return index, rows
        finite = finite_rows(rows)
        return index[finite], rows[finite]

    def __call__(self, frame: Frame) -> Keypoints3D:
        index, rows = self.finite_candidates(frame)
        keep = cap(index.size, self.conf["max_keypoints"], self.conf["seed"], frame)
        if keep.size < index.size:
            index, rows = index[keep], np.take(rows, keep, axis=0)
        return keypoints(index, rows)


class DepthExtractor(EdgeExtractor3D):
    """Depth-discontinuous points: |r_{i+1} - r_i| / r_i > eps_D along a ring (module docstring: which point)."""

    name = "depth"
    default_conf: ClassVar[dict[str, Any]] = {**CAP_CONF, "eps_depth": 0.1}  # eps_D, relative range change

    def candidates(self, frame: Frame) -> np.ndarray:
        return depth_edges(frame, self.conf["eps_depth"])


class ReflectanceExtractor(EdgeExtractor3D):
    """Reflectance-discontinuous points: |R_{i+1} - R_i| > eps_R along a ring, same selection rule as depth."""

    name = "reflectance"
    default_conf: ClassVar[dict[str, Any]] = {**CAP_CONF, "eps_reflectance": 0.2}  # eps_R, absolute change in [0, 1]

    def candidates(self, frame: Frame) -> np.ndarray:
        return reflectance_edges(frame, self.conf["eps_reflectance"])


class DepthReflectanceExtractor(EdgeExtractor3D):
    """The paper's 3D edge points: the union of depth and reflectance discontinuities, then the cap."""

    name = "depth+reflectance"
    default_conf: ClassVar[dict[str, Any]] = {**CAP_CONF, "eps_depth": 0.1, "eps_reflectance": 0.2}

    def candidates(self, frame: Frame) -> np.ndarray:
        lines = ScanLines(frame)  # one mask for both rules: the union needs no sort or dedup
        lines.mark_depth(self.conf["eps_depth"])
        lines.mark_reflectance(self.conf["eps_reflectance"])
        return lines.marked()


class RandomExtractor3D(EdgeExtractor3D):
    """max_keypoints points drawn uniformly without replacement from the whole sweep: the no-edge baseline."""

    name = "random"

    def candidates(self, frame: Frame) -> np.ndarray:
        return np.arange(frame.points.shape[0], dtype=np.int64)

    def __call__(self, frame: Frame) -> Keypoints3D:
        points = frame.points
        # a whole finite scan (the usual case): the candidates are all points and the cap's positions are their
        # indices, with no index list built
        if all_finite(points):
            index = cap(len(points), self.conf["max_keypoints"], self.conf["seed"], frame)
            return keypoints(index, np.take(points, index, axis=0))
        return super().__call__(frame)
