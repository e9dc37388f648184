"""Overlays: points land on the pixels geometry.project says, nearer points win, colours follow distance, and
`i2pbench viz` writes the expected figure for a real KITTI frame."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from conftest import SAMPLE_DATA, sample

from i2pbench.cli import main
from i2pbench.commands.viz import resolve_frame
from i2pbench.geometry.transforms import in_image, project
from i2pbench.registry.build import default_registry
from i2pbench.report import draw, overlay
from i2pbench.stages.pipeline import Combination, Pipeline
from i2pbench.testing.frames import kitti_frame, synthetic_frame, with_image

KITTI = SAMPLE_DATA / "kitti_odometry"
MARK = np.array([255, 0, 255], np.uint8)  # a colour no other drawing uses, on a black canvas


def marked_pixels(canvas: np.ndarray) -> set[tuple[int, int]]:
    rows, cols = np.nonzero((canvas == MARK).all(axis=2))
    return set(zip(cols.tolist(), rows.tolist(), strict=True))


def expected_pixels(K, T, xyz, size) -> set[tuple[int, int]]:
    """Pixels straight from geometry.project, rounded to the nearest pixel centre."""
    uv, front = project(K, T, np.asarray(xyz, np.float64))
    keep = in_image(uv, front, size)
    px = np.clip(np.rint(uv[keep]).astype(int), 0, [size[0] - 1, size[1] - 1])
    return set(map(tuple, px.tolist()))


def test_hand_worked_projection_lands_on_the_expected_pixels():
    K = np.array([[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]])
    xyz = np.array([[0, 0, 10], [1, -0.5, 10], [0, 0, -10], [100, 0, 10]])  # centre, offset, behind, outside
    uv, distance, rows = draw.project_points(K, np.eye(4), xyz, (100, 80))
    assert rows.tolist() == [0, 1]
    np.testing.assert_allclose(uv, [[50, 40], [60, 35]])
    np.testing.assert_allclose(distance, [10, np.sqrt(101.25)])
    canvas = draw.draw_points(np.zeros((80, 100, 3), np.uint8), uv, MARK, distance, radius=0)
    assert marked_pixels(canvas) == {(50, 40), (60, 35)}


def test_points_are_drawn_where_geometry_project_puts_them_on_a_real_frame():
    sample("kitti_odometry")
    frame = kitti_frame(str(KITTI))
    uv, distance, _ = draw.project_points(frame.K, frame.T_gt, frame.points[:, :3], frame.image_size)
    w, h = frame.image_size
    canvas = draw.draw_points(np.zeros((h, w, 3), np.uint8), uv, MARK, distance, radius=0)
    expected = expected_pixels(frame.K, frame.T_gt, frame.points[:, :3], frame.image_size)
    assert len(expected) > 5000  # a KITTI scan puts ~20k points in the image
    assert marked_pixels(canvas) == expected


def test_radius_paints_the_square_around_the_pixel_and_stays_inside_the_image():
    canvas = draw.draw_points(np.zeros((10, 10, 3), np.uint8), np.array([[0.2, 4.0]]), MARK, radius=1)
    assert marked_pixels(canvas) == {(c, r) for c in (0, 1) for r in (3, 4, 5)}


def test_the_nearest_point_wins_a_shared_pixel_whatever_the_drawing_order():
    uv = np.array([[3.0, 3.0], [3.1, 2.9], [3.0, 3.2]])
    colours = np.array([[10, 0, 0], [20, 0, 0], [30, 0, 0]], np.uint8)
    depth = np.array([5.0, 2.0, 9.0])
    for order in ([0, 1, 2], [2, 1, 0], [1, 2, 0]):
        canvas = draw.draw_points(np.zeros((6, 6, 3), np.uint8), uv[order], colours[order], depth[order], radius=0)
        assert canvas[3, 3, 0] == 20


def test_near_is_warm_and_far_is_cool():
    near, middle, far = draw.distance_colours(np.array([1.0, 20.0, 80.0])).astype(int)
    assert near[0] > near[2] and far[2] > far[0]
    assert not (near == middle).all() and not (middle == far).all()
    beyond = draw.distance_colours(np.array([draw.FAR_M, 500.0]))
    np.testing.assert_array_equal(beyond[0], beyond[1])  # the scale saturates past FAR_M


def test_resolve_frame_takes_ids_and_indices():
    ids = ["00/000000", "00/000001", "7"]
    assert resolve_frame(ids, "00/000001") == "00/000001"
    assert resolve_frame(ids, "1") == "00/000001"
    assert resolve_frame(ids, "7") == "7"  # an id that looks like a number stays an id


def test_the_run_s_trace_holds_what_the_viz_panels_draw():
    registry = default_registry()
    frame = synthetic_frame(seed=1)
    names = {"extractor2d": "lsd", "extractor3d": "depth+reflectance", "matcher": "oracle", "solver": "epnp-ransac"}
    outcome = Pipeline.build(registry, Combination(names), timeout_s=None).run(frame)
    assert len(outcome.kp2d) == outcome.n_kp2d > 0 and len(outcome.kp3d) == outcome.n_kp3d > 0
    assert len(outcome.matches) == outcome.n_matches > 0
    np.testing.assert_array_equal(outcome.matched_uv, outcome.kp2d.uv[outcome.matches.index2d])
    assert outcome.estimate is outcome.records[-1].output  # the solver's own estimate, not a recomputation


def test_a_failed_pose_leaves_the_predicted_panel_as_the_bare_image():
    frame = synthetic_frame(seed=2)
    panels = overlay.pose_panels(frame, None, failure="solver 'x': too few matches")
    assert panels[2][0] == ["predicted: failed: solver 'x': too few matches"]
    np.testing.assert_array_equal(panels[2][1], draw.background(frame.image))
    black = with_image(frame, np.zeros_like(frame.image))
    assert overlay.points_panel(black, black.T_gt).any()


@pytest.fixture(scope="module")
def kitti_viz(tmp_path_factory):
    """`i2pbench viz` on the first real KITTI frame with every panel, run once for the tests below."""
    sample("kitti_odometry")
    out = tmp_path_factory.mktemp("viz") / "frame.png"
    argv = [
        "viz",
        "00/000000",
        "--preset",
        "classic-oracle",
        "--dataset",
        "kitti",
        "--split",
        "all",
        "--data-root",
        str(KITTI),
        "--out",
        str(out),
        "--edges",
        "--matches",
    ]
    assert main(argv) == 0
    return cv2.imread(str(out))[:, :, ::-1], kitti_frame(str(KITTI))


def test_viz_writes_five_panels_of_the_expected_size(kitti_viz):
    image, frame = kitti_viz
    w, h = overlay.figure_size(frame, 5)
    assert image.shape == (h + draw.CAPTION_PX, w, 3)  # the first panel carries one more caption line (the title)


def test_viz_ground_truth_panel_is_the_projection_under_t_gt(kitti_viz):
    image, frame = kitti_viz
    w, h = frame.image_size
    top = 2 * draw.CAPTION_PX + h + draw.CAPTION_PX  # title + first caption, first panel, second caption
    np.testing.assert_array_equal(image[top : top + h], overlay.points_panel(frame, frame.T_gt))
    assert not np.array_equal(image[top : top + h], draw.background(frame.image))


def test_viz_refuses_more_than_one_combination(capsys):
    sample("kitti_odometry")
    argv = [
        "viz",
        "0",
        "--preset",
        "classic-oracle",
        "--extractor",
        "lsd,canny",
        "--dataset",
        "kitti",
        "--split",
        "all",
        "--data-root",
        str(KITTI),
    ]
    assert main(argv) == 2
    assert "viz draws one combination" in capsys.readouterr().err
