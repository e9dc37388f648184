"""Classic extractors on hand-built scan lines and a drawn rectangle, with the selected indices worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest
from i2pbench_classic.capping import cap
from i2pbench_classic.extract2d import (
    CannyExtractor,
    GridExtractor2D,
    LSDExtractor,
    RandomExtractor2D,
    SobelExtractor,
    rasterise_segments,
)
from i2pbench_classic.extract3d import (
    DepthExtractor,
    DepthReflectanceExtractor,
    RandomExtractor3D,
    ReflectanceExtractor,
)

from i2pbench.types import Frame

K = np.array([[700.0, 0.0, 150.0], [0.0, 700.0, 100.0], [0.0, 0.0, 1.0]])


def scan_frame(ranges, reflectance=None, ring=None, frame_id="f0", image=None) -> Frame:
    """A frame whose points lie on the x axis at the given ranges (only ranges, ring and reflectance matter)."""
    r = np.asarray(ranges, dtype=np.float32)
    refl = np.zeros_like(r) if reflectance is None else np.asarray(reflectance, dtype=np.float32)
    points = np.stack([r, np.zeros_like(r), np.zeros_like(r), refl], axis=1)
    ring = np.zeros(len(r), np.int16) if ring is None else np.asarray(ring, dtype=np.int16)
    image = np.zeros((200, 300, 3), np.uint8) if image is None else image
    return Frame("toy", frame_id, image, points, ring, r, K, None)


def image_frame(gray: np.ndarray, frame_id: str = "img") -> Frame:
    return scan_frame([1.0], frame_id=frame_id, image=np.repeat(gray[:, :, None], 3, axis=2))


def selected(extractor, frame) -> list[int]:
    return extractor(frame).index.tolist()


# --- depth: r = 10 10 10 10 20 20 20 20 10 10 10 (indices 0..10)
# rise at i = 3 (dr/r = 10/10 = 1 > 0.1) selects i-1 = 2; drop at i = 7 (dr/r = -10/20 = -0.5) selects i+1 = 8.
STEP = [10, 10, 10, 10, 20, 20, 20, 20, 10, 10, 10]


def test_depth_rise_selects_previous_point_and_drop_selects_next():
    assert selected(DepthExtractor(), scan_frame(STEP)) == [2, 8]


def test_depth_selection_is_on_the_near_side():
    r = np.array(STEP)
    for i in selected(DepthExtractor(), scan_frame(STEP)):
        assert r[i] == r.min()


def test_depth_threshold_is_strict_and_relative_to_r_i():
    assert selected(DepthExtractor(), scan_frame([10, 10, 11, 11])) == []  # 1/10 = eps_D exactly: not selected
    assert selected(DepthExtractor(), scan_frame([10, 10, 11.2, 11.2])) == [0]  # 0.12 > 0.1
    # a drop 20 -> 17.5 is -2.5/20 = -0.125 (selected); 20 -> 18.5 is -0.075 (not)
    assert selected(DepthExtractor(), scan_frame([20, 20, 17.5, 17.5])) == [2]
    assert selected(DepthExtractor(), scan_frame([20, 20, 18.5, 18.5])) == []


def test_depth_eps_is_configurable():
    assert selected(DepthExtractor({"eps_depth": 0.05}), scan_frame([10, 10, 10.6, 10.6])) == [0]


def test_depth_one_point_wide_object_keeps_the_literal_rule():
    # far, near, far at 1, 2, 3: the drop at 1 selects 2 (near), the rise at 2 selects 1 (far)
    assert selected(DepthExtractor(), scan_frame([30, 30, 10, 30, 30])) == [1, 2]


def test_depth_ignores_jumps_across_rings_and_rises_at_a_ring_start():
    ring = [0, 0, 0, 1, 1, 1]
    assert selected(DepthExtractor(), scan_frame([10, 10, 10, 30, 30, 30], ring=ring)) == []
    # ring 1 rises at its first point (5 -> 20): i-1 would be in ring 0, so nothing is selected
    assert selected(DepthExtractor(), scan_frame([10, 10, 10, 5, 20, 20], ring=ring)) == []
    assert selected(DepthExtractor(), scan_frame([10, 20, 20])) == []  # rise at i = 0: no i-1


def test_depth_follows_ring_order_when_rings_are_interleaved():
    # ring 0 holds points 0, 2, 4, 6 with r = 10 10 20 20: the rise at its 2nd point selects its 1st (point 0)
    frame = scan_frame([10, 20, 10, 20, 20, 20, 20, 20], ring=[0, 1, 0, 1, 0, 1, 0, 1])
    assert selected(DepthExtractor(), frame) == [0]


def test_depth_ignores_points_without_a_return():
    assert selected(DepthExtractor(), scan_frame([0, 10, 10, 10])) == []


def test_points_with_non_finite_coordinates_are_never_selected():
    frame = scan_frame(STEP)
    frame.points[8, :3] = np.nan  # the drop's target (see STEP) is a corrupt return
    assert selected(DepthExtractor(), frame) == [2]
    frame.points[:5, 0] = np.inf
    assert selected(RandomExtractor3D({"max_keypoints": None}), frame) == [5, 6, 7, 9, 10]


# --- reflectance: R = .1 .1 .5 .5 .5 .2 .2; rise at 1 (+0.4) selects 0, drop at 4 (-0.3) selects 5; +-0.15 never.
REFL = [0.1, 0.1, 0.5, 0.5, 0.5, 0.2, 0.2]


def test_reflectance_rule():
    assert selected(ReflectanceExtractor(), scan_frame([10] * 7, REFL)) == [0, 5]
    assert selected(ReflectanceExtractor(), scan_frame([10] * 4, [0.1, 0.1, 0.25, 0.25])) == []


def test_reflectance_on_a_0_255_scale_is_normalised():
    assert selected(ReflectanceExtractor(), scan_frame([10] * 7, np.array(REFL) * 255 / 0.5)) == [0, 5]


def test_union_of_depth_and_reflectance():
    refl = [0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.5, 0.5, 0.5, 0.5, 0.5]  # rise at 5 selects 4
    frame = scan_frame(STEP, refl)
    assert selected(DepthExtractor(), frame) == [2, 8]
    assert selected(ReflectanceExtractor(), frame) == [4]
    assert selected(DepthReflectanceExtractor(), frame) == [2, 4, 8]


def test_keypoints3d_carry_the_selected_points():
    frame = scan_frame(STEP, np.linspace(0, 0.1, 11))
    kp = DepthExtractor()(frame)
    np.testing.assert_array_equal(kp.xyz, frame.points[[2, 8], :3])
    np.testing.assert_array_equal(kp.reflectance, frame.points[[2, 8], 3])


def alternating(n=1000, frame_id="f0") -> Frame:
    return scan_frame(np.tile([10.0, 20.0], n // 2), frame_id=frame_id)


def test_3d_cap_is_a_sorted_seeded_subset():
    every = selected(DepthExtractor({"max_keypoints": None}), alternating())
    # rises at even i select the odd i-1 = 1..997 (none for i = 0); drops at odd i <= 997 select i+1 = 2..998
    assert every == list(range(1, 999))
    capped = selected(DepthExtractor({"max_keypoints": 100}), alternating())
    assert len(capped) == 100 and capped == sorted(capped) and set(capped) <= set(every)
    assert capped == selected(DepthExtractor({"max_keypoints": 100}), alternating())
    assert capped != selected(DepthExtractor({"max_keypoints": 100, "seed": 1}), alternating())
    assert capped != selected(DepthExtractor({"max_keypoints": 100}), alternating(frame_id="f1"))


def test_3d_default_cap_is_3000():
    assert len(DepthReflectanceExtractor()(alternating(8000))) == 3000


def test_random_3d_is_uniform_subset():
    frame = scan_frame(np.ones(5000))
    kp = RandomExtractor3D({"max_keypoints": 50})(frame)
    assert len(np.unique(kp.index)) == 50 and kp.index.max() < 5000
    np.testing.assert_array_equal(kp.index, RandomExtractor3D({"max_keypoints": 50})(frame).index)


# --- 2D: a filled 100 x 100 white square, rows 50..149 and columns 100..199, on black.
def square() -> np.ndarray:
    gray = np.zeros((200, 300), np.uint8)
    gray[50:150, 100:200] = 255
    return gray


def distance_to_square_outline(uv: np.ndarray) -> np.ndarray:
    """Distance of pixel centres to the square's outline (the lines x = 99.5, 199.5 and y = 49.5, 149.5)."""
    u, v = uv[:, 0], uv[:, 1]
    dx = np.minimum(np.abs(u - 99.5), np.abs(u - 199.5))
    dy = np.minimum(np.abs(v - 49.5), np.abs(v - 149.5))
    on_vertical = (v >= 48) & (v <= 151)
    on_horizontal = (u >= 98) & (u <= 201)
    return np.minimum(np.where(on_vertical, dx, np.inf), np.where(on_horizontal, dy, np.inf))


def test_rasterise_segments_hand_example():
    # (0,0) -> (4,2): 4 steps of 1 px in u, v = 0, .5, 1, 1.5, 2 rounded half up -> 0, 1, 1, 2, 2
    mask = rasterise_segments(np.array([[0.0, 0.0, 4.0, 2.0]]), (6, 4))
    rows, cols = np.nonzero(mask)
    assert sorted(zip(cols.tolist(), rows.tolist(), strict=True)) == [(0, 0), (1, 1), (2, 1), (3, 2), (4, 2)]


def test_rasterise_segments_drops_pixels_outside_and_deduplicates():
    mask = rasterise_segments(np.array([[-2.0, 0.0, 2.0, 0.0], [0.0, 0.0, 2.0, 0.0]]), (2, 1))
    assert mask.tolist() == [[True, True]]


def test_lsd_pixels_lie_on_the_square_outline():
    kp = LSDExtractor({"max_keypoints": None})(image_frame(square()))
    assert kp.uv.dtype == np.float32
    assert np.all(distance_to_square_outline(kp.uv) <= 1.0)
    # four sides of about 98 px (LSD stops a little short of the corners), none shared
    assert 370 <= len(kp) <= 400
    left = np.sum(np.abs(kp.uv[:, 0] - 99.5) <= 1)
    top = np.sum(np.abs(kp.uv[:, 1] - 49.5) <= 1)
    assert left >= 90 and top >= 90


def test_sobel_marks_both_sides_of_every_edge():
    # every pixel whose 3x3 window holds both values: the square's border ring (4*100 - 4) and the ring just
    # outside it (4*102 - 4); all have magnitude >= 255*sqrt(2) > 150
    kp = SobelExtractor({"max_keypoints": None})(image_frame(square()))
    assert len(kp) == 396 + 404
    assert np.all(distance_to_square_outline(kp.uv) <= 1.0)


def test_canny_pixels_lie_on_the_square_outline():
    kp = CannyExtractor({"max_keypoints": None})(image_frame(square()))
    assert 390 <= len(kp) <= 410  # one pixel-wide outline
    assert np.all(distance_to_square_outline(kp.uv) <= 1.0)


def test_flat_image_has_no_edges():
    flat = image_frame(np.full((200, 300), 90, np.uint8))
    for extractor in (LSDExtractor(), CannyExtractor(), SobelExtractor()):
        assert extractor(flat).uv.shape == (0, 2)


@pytest.mark.parametrize("cls", [LSDExtractor, CannyExtractor, SobelExtractor])
def test_2d_cap_is_a_sorted_seeded_subset(cls):
    frame = image_frame(square())
    every = cls({"max_keypoints": None})(frame).uv
    capped = cls({"max_keypoints": 100})(frame).uv
    assert capped.shape == (100, 2)
    assert {tuple(p) for p in capped.tolist()} <= {tuple(p) for p in every.tolist()}
    raster = capped[:, 1] * 1000 + capped[:, 0]
    assert np.all(np.diff(raster) > 0)
    np.testing.assert_array_equal(capped, cls({"max_keypoints": 100})(frame).uv)


def test_random_2d_pixels_are_distinct_seeded_and_inside():
    frame = image_frame(square())
    uv = RandomExtractor2D()(frame).uv
    assert uv.shape == (3000, 2) and len({tuple(p) for p in uv.tolist()}) == 3000
    assert uv[:, 0].min() >= 0 and uv[:, 0].max() <= 299 and uv[:, 1].min() >= 0 and uv[:, 1].max() <= 199
    np.testing.assert_array_equal(uv, RandomExtractor2D()(frame).uv)
    assert not np.array_equal(uv, RandomExtractor2D({"seed": 7})(frame).uv)


# --- grid: the centres of whole stride x stride cells


def blank_frame(width: int, height: int, frame_id: str = "g") -> Frame:
    return scan_frame([1.0], frame_id=frame_id, image=np.zeros((height, width, 3), np.uint8))


def test_the_grid_is_the_centres_of_whole_cells_in_raster_order():
    # 20 x 18 pixels at stride 8: 2 whole columns (0-7, 8-15; 16-19 is partial) and 2 whole rows (0-7, 8-15)
    uv = GridExtractor2D()(blank_frame(20, 18)).uv
    np.testing.assert_array_equal(uv, [[3.5, 3.5], [11.5, 3.5], [3.5, 11.5], [11.5, 11.5]])
    assert uv.dtype == np.float32
    np.testing.assert_array_equal(GridExtractor2D({"stride": 3})(blank_frame(3, 3)).uv, [[1.0, 1.0]])
    assert len(GridExtractor2D()(blank_frame(7, 100)).uv) == 0  # narrower than one cell


def test_the_grid_cap_is_the_seeded_subset_of_the_other_extractors():
    capped = GridExtractor2D({"max_keypoints": 3})
    frame = blank_frame(40, 40)  # 25 cells
    first = capped(frame).uv
    every = GridExtractor2D()(frame).uv
    np.testing.assert_array_equal(first, every[cap(len(every), 3, 0, frame)])  # the shared rule, in raster order
    np.testing.assert_array_equal(capped(frame).uv, first)
    others = [capped(blank_frame(40, 40, f"g{i}")).uv for i in range(5)]
    assert any(not np.array_equal(o, first) for o in others)  # seeded by the frame, not fixed


def test_a_stride_below_one_is_refused_with_a_message():
    with pytest.raises(ValueError, match="stride must be a positive"):
        GridExtractor2D({"stride": 0})(blank_frame(8, 8))


def test_the_grid_extractor_conforms():
    from i2pbench.testing import check_component

    report = check_component(GridExtractor2D, {"stride": 8, "max_keypoints": 50})
    assert not list(report), str(report)
