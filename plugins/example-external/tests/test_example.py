"""The example plugin's own tests: the i2pbench conformance kit on each component, and hand-worked behaviour."""

import dataclasses

import numpy as np
import pytest
from i2pbench.testing import assert_conforms, registered_components, synthetic_frame

from i2pbench_example import plugin
from i2pbench_example.curvature import CurvatureExtractor, surface_variation
from i2pbench_example.harris import HarrisExtractor


@pytest.mark.parametrize("cls", registered_components(plugin), ids=lambda cls: cls.name)
def test_conforms(cls):
    assert_conforms(cls)


def test_harris_finds_the_four_corners_of_a_white_square():
    image = np.zeros((60, 80, 3), np.uint8)
    image[20:40, 30:50] = 255  # corners at pixels (30, 20), (49, 20), (30, 39), (49, 39)
    frame = dataclasses.replace(synthetic_frame(), image=image)
    uv = HarrisExtractor({"max_keypoints": 4, "min_distance": 5})(frame).uv
    expected = np.array([[30, 20], [49, 20], [30, 39], [49, 39]], np.float32)
    nearest = np.linalg.norm(uv[:, None] - expected[None], axis=2).min(axis=0)
    assert len(uv) == 4 and nearest.max() <= 1.5


def test_surface_variation_is_zero_on_a_plane_and_high_on_a_crease():
    grid = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), axis=-1).reshape(-1, 2)
    floor = np.c_[grid, np.zeros(len(grid))]  # z = 0
    wall = np.c_[grid[:, 0], np.zeros(len(grid)), grid[:, 1] + 1]  # y = 0, meeting the floor along the x axis
    assert np.allclose(surface_variation(floor, 8), 0.0, atol=1e-12)
    points = np.r_[floor, wall]
    variation = surface_variation(points, 8)
    from_crease = np.where(points[:, 2] == 0, points[:, 1], points[:, 2])  # grid steps to the line y = z = 0
    assert variation[from_crease == 0].min() > 0.1  # a neighbourhood bent by 90 degrees
    assert np.allclose(variation[from_crease >= 2], 0.0, atol=1e-12)  # neighbours all on one plane


def test_curvature_keeps_the_most_curved_points_in_point_order():
    frame = synthetic_frame()
    kp = CurvatureExtractor({"max_keypoints": 5, "threshold": 0.0})(frame)
    variation = surface_variation(frame.points[:, :3].astype(np.float64), 10)
    assert len(kp) == 5 and np.all(np.diff(kp.index) > 0)
    assert variation[kp.index].min() >= np.sort(variation)[-5]
