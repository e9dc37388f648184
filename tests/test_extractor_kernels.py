"""The fast paths of the classic extractors give exactly what the plain numpy formulations give.

The extractors were rewritten for speed (one selection mask for both scan-line rules, OpenCV's findNonZero for mask
pixels, np.take for row gathers, a whole-scan finiteness check, a cheaper seeded draw and sort in the cap, keypoints
packed column by column); each is compared here with the straightforward formulation it replaced, on hand-built
arrays and on real KITTI scans made harder (shuffled ring order, NaN points, zero ranges).
"""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest
from i2pbench_classic.capping import cap
from i2pbench_classic.extract2d import CannyExtractor, RandomExtractor2D, SobelExtractor, edge_pixels, grayscale
from i2pbench_classic.extract3d import (
    DepthExtractor,
    DepthReflectanceExtractor,
    RandomExtractor3D,
    ReflectanceExtractor,
    all_finite,
    finite_rows,
    normalised_reflectance,
)

from i2pbench.types import Frame, Keypoints3D


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


def plain_cap(candidates: int, max_keypoints: int | None, seed: int, frame: Frame) -> np.ndarray:
    """the cap as first written: the sha256 words as a list of ints, numpy's default (shuffled) draw, an int64 sort"""
    if max_keypoints is None or candidates <= max_keypoints:
        return np.arange(candidates, dtype=np.int64)
    digest = hashlib.sha256(f"{seed}\x00{frame.dataset}\x00{frame.frame_id}".encode()).digest()
    rng = np.random.default_rng(np.frombuffer(digest, dtype=np.uint32).tolist())
    return np.sort(rng.choice(candidates, size=int(max_keypoints), replace=False)).astype(np.int64)


def test_cap_equals_the_plain_draw_on_every_branch():
    """numpy's Floyd and tail-shuffle branches (around 10,000 candidates and k = n // 50, n // 20), the mask sort and
    the int32 sort (around 32 candidates per kept one), and the edges (k of 0 and 1, k = n - 1)"""
    frame = Frame("toy", "f0", np.zeros((1, 1, 3), np.uint8), np.zeros((0, 4), np.float32), None, None, None, None)
    cases = [(n, k) for n in (2, 999, 3938, 10_000, 10_001, 10_156) for k in (0, 1, 150, 200, 201, 3000, n - 1)]
    cases += [(n, k) for n in (46_100, 120_268, 465_750) for k in (1, n // 50, n // 50 + 1, n // 20, n // 20 + 1)]
    cases += [(n, 3000) for n in (3001, 95_999, 96_000, 96_001, 120_268, 465_750)]
    for n, k in cases:
        if k >= n:
            continue
        for seed in (0, 5):
            got = cap(n, k, seed, frame)
            assert got.dtype == np.int64 and np.array_equal(got, plain_cap(n, k, seed, frame)), (n, k, seed)
    assert np.array_equal(cap(7, None, 0, frame), np.arange(7)) and np.array_equal(cap(7, 7, 0, frame), np.arange(7))
    with pytest.raises(ValueError):
        cap(7, -1, 0, frame)


def test_all_finite_matches_isfinite_all():
    rng = np.random.default_rng(0)
    values = rng.normal(size=(1000, 4)).astype(np.float32)
    assert all_finite(values) and all_finite(values[:0])
    for bad in (np.nan, np.inf, -np.inf):
        broken = values.copy()
        broken[517, 3] = bad
        assert not all_finite(broken)
    both = values.copy()
    both[3, 0], both[9, 1] = np.inf, -np.inf  # inf - inf: a NaN sum, still non-finite
    assert not all_finite(both)
    huge = np.full((100, 4), 3e38, np.float32)  # finite, but their sum overflows: the plain test decides
    assert all_finite(huge)
    huge[50, 2] = np.nan
    assert not all_finite(huge)


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
    from i2pbench.scoring.protocol import Protocol

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


@pytest.mark.parametrize("extractor", [DepthReflectanceExtractor, RandomExtractor3D])
def test_keypoints3d_are_packed_as_from_index_packs_them(real_frames, extractor):
    for frame in (real_frames[0], real_frames[2]):
        for conf in ({}, {"max_keypoints": None}, {"max_keypoints": 0}):
            kp = extractor(conf)(frame)
            plain = Keypoints3D.from_index(frame, kp.index)
            for ours, theirs in ((kp.index, plain.index), (kp.xyz, plain.xyz), (kp.reflectance, plain.reflectance)):
                assert ours.dtype == theirs.dtype and ours.shape == theirs.shape and ours.flags.c_contiguous
                assert np.array_equal(ours, theirs)


@pytest.mark.parametrize("extractor", [CannyExtractor, SobelExtractor])
def test_edge_extractors_equal_nonzero_pixels_capped_and_stacked(real_frames, extractor):
    """the 2D edge extractors against the plain formulation: np.nonzero of the mask, the plain cap, a stack of (u, v)"""
    frame = real_frames[0]
    for conf in ({}, {"max_keypoints": None}, {"max_keypoints": 0}):
        ex = extractor(conf)
        rows, cols = np.nonzero(ex.edge_mask(grayscale(frame.image)))
        keep = plain_cap(len(rows), ex.conf["max_keypoints"], 0, frame)
        uv = np.stack([cols[keep], rows[keep]], axis=1).astype(np.float32).reshape(-1, 2)
        got = ex(frame).uv
        assert got.dtype == np.float32 and got.flags.c_contiguous and np.array_equal(got, uv)


def test_random_pixels_equal_the_plain_draw_stacked(real_frames):
    frame = real_frames[0]
    width, height = frame.image_size
    for conf in ({}, {"max_keypoints": 1}, {"max_keypoints": 0}):
        ex = RandomExtractor2D(conf)
        rows, cols = np.divmod(plain_cap(width * height, ex.conf["max_keypoints"], 0, frame), width)
        got = ex(frame).uv
        assert got.dtype == np.float32 and got.flags.c_contiguous
        assert np.array_equal(got, np.stack([cols, rows], axis=1).astype(np.float32).reshape(-1, 2))


def test_random_points_are_drawn_from_the_finite_ones_with_or_without_a_corrupt_point(real_frames):
    clean, corrupt = real_frames[0], real_frames[2]
    for frame in (clean, corrupt):
        finite = np.flatnonzero(np.isfinite(frame.points).all(axis=1))
        drawn = RandomExtractor3D({"max_keypoints": 700})(frame)
        assert np.array_equal(drawn.index, finite[cap(finite.size, 700, 0, frame)])
    assert len(np.flatnonzero(~np.isfinite(corrupt.points).all(axis=1))) > 0  # the slow path did run
