"""The fast paths of the classic extractors give exactly what the plain numpy formulations give.

The extractors were rewritten for speed (one selection mask for both scan-line rules, OpenCV's findNonZero for mask
pixels, np.take for row gathers, a whole-scan finiteness check); each is compared here with the straightforward
formulation it replaced, on hand-built arrays and on real KITTI scans made harder (shuffled ring order, NaN points,
zero ranges).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from i2pbench_classic.capping import cap
from i2pbench_classic.extract2d import edge_pixels
from i2pbench_classic.extract3d import (
    DepthExtractor,
    DepthReflectanceExtractor,
    RandomExtractor3D,
    ReflectanceExtractor,
    finite_rows,
    normalised_reflectance,
)

from i2pbench.types import Frame


def reference_edges(frame: Frame, eps_depth: float | None, eps_reflectance: float | None) -> np.ndarray:
    """the paper's rule as index lists (how the extractor used to compute it): per rule, rises select i-1 and drops
    i+1 along a ring in scan order; the union sorted and deduplicated; non-finite points dropped."""
    order = np.argsort(frame.ring, kind="stable")
    ring = frame.ring[order]
    same = ring[1:] == ring[:-1]
    picked = []
    rules = []
    if eps_depth is not None:
        r = frame.ranges.astype(np.float64)[order]
        rules.append((np.divide(np.diff(r), r[:-1], out=np.zeros(len(r) - 1), where=r[:-1] > 0), eps_depth))
    if eps_reflectance is not None:
        rules.append((np.diff(normalised_reflectance(frame.points)[order]), eps_reflectance))
    for delta, eps in rules:
        rise, drop = same & (delta > eps), same & (delta < -eps)
        picked += [np.flatnonzero(rise[1:] & same[:-1]), np.flatnonzero(drop) + 1]
    index = np.unique(order[np.concatenate(picked)]) if picked else np.zeros(0, np.int64)
    return index[np.isfinite(frame.points[index]).all(axis=1)]


def test_finite_rows_matches_all_over_each_width():
    rng = np.random.default_rng(0)
    for width in (1, 2, 3, 4, 5, 8):
        values = rng.normal(size=(50, width)).astype(np.float32)
        values[rng.integers(0, 50, 12), rng.integers(0, width, 12)] = rng.choice([np.nan, np.inf, -np.inf], 12)
        assert np.array_equal(finite_rows(values), np.isfinite(values).all(axis=1)), width
    strided = np.ones((4, 8), np.float32)[:, ::2]  # not contiguous: the plain path
    strided[2, 1] = np.nan
    assert finite_rows(strided).tolist() == [True, True, False, True]


def test_edge_pixels_lists_mask_pixels_in_raster_order_like_nonzero():
    mask = np.zeros((3, 4), bool)
    mask[0, 3] = mask[2, 0] = mask[2, 2] = mask[1, 1] = True
    rows, cols = edge_pixels(mask)
    assert rows.tolist() == [0, 1, 2, 2] and cols.tolist() == [3, 1, 0, 2]  # by hand: row by row, left to right
    canny_like = mask.astype(np.uint8) * 255
    assert [a.tolist() for a in edge_pixels(canny_like)] == [rows.tolist(), cols.tolist()]
    empty_rows, empty_cols = edge_pixels(np.zeros((3, 4), bool))
    assert empty_rows.size == empty_cols.size == 0


def harder(frame: Frame, seed: int) -> Frame:
    """the frame with its points shuffled across rings, 1% NaN points and 1% zero ranges"""
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(frame.points))
    points, ranges = frame.points[perm].copy(), frame.ranges[perm].copy()
    points[rng.choice(len(points), len(points) // 100)] = np.nan
    ranges[rng.choice(len(ranges), len(ranges) // 100)] = 0
    return dataclasses.replace(frame, points=points, ring=frame.ring[perm], ranges=ranges)


@pytest.fixture
def real_frames(shared_data):
    from i2pbench.data.kitti import KittiOdometry
    from i2pbench.protocol import Protocol

    data = KittiOdometry("all", {"root": str(shared_data / "kitti_odometry")})
    frames = [Protocol().apply(data.load(frame_id)) for frame_id in data.frame_ids()[:2]]
    return [*frames, harder(frames[0], 1), harder(frames[1], 2)]


@pytest.mark.parametrize(
    "extractor, eps",
    [(DepthExtractor, (0.1, None)), (ReflectanceExtractor, (None, 0.2)), (DepthReflectanceExtractor, (0.1, 0.2))],
)
def test_scanline_extractors_equal_the_index_list_rule_on_real_scans(real_frames, extractor, eps):
    for frame in real_frames:
        expected = reference_edges(frame, *eps)
        assert expected.size > 1000  # real edges, not a vacuous comparison
        everything = extractor({"max_keypoints": None})(frame)
        assert np.array_equal(everything.index, expected)
        capped = extractor({"max_keypoints": 500})(frame)
        assert np.array_equal(capped.index, expected[cap(expected.size, 500, 0, frame)])
        assert np.array_equal(capped.xyz, frame.points[capped.index, :3])


def test_random_points_are_drawn_from_the_finite_ones_with_or_without_a_corrupt_point(real_frames):
    clean, corrupt = real_frames[0], real_frames[2]
    for frame in (clean, corrupt):
        finite = np.flatnonzero(np.isfinite(frame.points).all(axis=1))
        drawn = RandomExtractor3D({"max_keypoints": 700})(frame)
        assert np.array_equal(drawn.index, finite[cap(finite.size, 700, 0, frame)])
    assert len(np.flatnonzero(~np.isfinite(corrupt.points).all(axis=1))) > 0  # the slow path did run
