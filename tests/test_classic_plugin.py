"""The classic plugin's registrations and the diagnostics on a hand-placed scene."""

from __future__ import annotations

import numpy as np
import pytest

from i2pbench.diagnostics.edges import edge_diagnostics, image_coverage, summarize_edge_diagnostics
from i2pbench.errors import PluginError
from i2pbench.registry.build import default_registry
from i2pbench.stages.pipeline import Combination, Pipeline
from i2pbench.types import Frame, Keypoints2D, Keypoints3D


def test_components_and_preset_are_registered():
    registry = default_registry()
    expected = {
        "extractor2d": {"lsd", "canny", "sobel", "random"},
        "extractor3d": {"depth", "reflectance", "depth+reflectance", "random"},
        "matcher": {"cosine", "oracle"},
        "solver": {"epnp-ransac", "poselib"},
    }
    for kind, names in expected.items():
        assert names <= set(registry.components[kind])
        assert all(registry.owner(kind, name) == "classic" for name in names)
    preset = registry.preset("classic-oracle")
    assert preset.combinations == (
        {"extractor2d": "lsd", "extractor3d": "depth+reflectance", "matcher": "oracle", "solver": "epnp-ransac"},
    )
    Pipeline.build(registry, Combination(preset.combinations[0]))  # a valid combination


def test_cosine_needs_encoders():
    names = {"extractor2d": "lsd", "extractor3d": "depth", "matcher": "cosine", "solver": "poselib"}
    with pytest.raises(PluginError, match="features2d"):
        Pipeline.build(default_registry(), Combination(names))


def test_image_coverage_hand_count():
    # pixels at distance < 3 from the centre of a 21 x 21 image: |dx|,|dy| <= 2 (25 of them); (3, 0) is at 3
    kp = Keypoints2D(np.array([[10, 10]], np.float32))
    assert image_coverage(kp, (21, 21), 3.0) == pytest.approx(25 / 441)
    assert image_coverage(Keypoints2D(np.zeros((0, 2), np.float32)), (21, 21), 3.0) == 0.0


class Fixed2D:
    name = "fixed2d"

    def __call__(self, frame):
        return Keypoints2D(np.array([[10, 10], [20, 15]], np.float32))


class All3D:
    name = "all3d"

    def __call__(self, frame):
        return Keypoints3D.from_index(frame, np.arange(len(frame.points)))


def test_edge_diagnostics_hand_scene():
    # camera = LiDAR, f = 10, centre (10, 10), 40 x 20 image. Points: (0,0,1) -> (10,10) on a keypoint;
    # (1,0.5,1) -> (20,15) on the other; (0.5,0,1) -> (15,10), 5 px away; (0,0,-1) behind; (5,0,1) -> (60,10) outside.
    xyz = np.array([[0, 0, 1], [1, 0.5, 1], [0.5, 0, 1], [0, 0, -1], [5, 0, 1]], np.float32)
    points = np.column_stack([xyz, np.zeros(5, np.float32)])
    K = np.array([[10.0, 0, 10], [0, 10.0, 10], [0, 0, 1]])
    frame = Frame(
        "toy",
        "f",
        np.zeros((20, 40, 3), np.uint8),
        points,
        np.zeros(5, np.int16),
        np.linalg.norm(xyz, axis=1),
        K,
        np.eye(4),
    )
    rows = edge_diagnostics([frame], Fixed2D(), All3D())
    row = rows.iloc[0]
    assert (row.n2d, row.n3d, row.n3d_in_fov, row.n3d_matched) == (2, 5, 3, 2)
    assert row.ratio_in_fov == pytest.approx(2 / 3) and row.ratio_all == pytest.approx(2 / 5)
    assert row.ratio2d == 1.0
    assert row.coverage2d == pytest.approx(50 / 800)  # two disjoint 25-pixel disks
    assert row.lift == pytest.approx((2 / 3) / (50 / 800))
    assert row.time2d_ms >= 0 and row.time3d_ms >= 0
    assert summarize_edge_diagnostics(rows).iloc[0].ratio_in_fov_pooled == pytest.approx(2 / 3)


def test_edge_diagnostics_needs_ground_truth():
    frame = Frame(
        "toy",
        "f",
        np.zeros((20, 40, 3), np.uint8),
        np.zeros((1, 4), np.float32),
        np.zeros(1, np.int16),
        np.ones(1, np.float32),
        np.eye(3),
        None,
    )
    with pytest.raises(ValueError, match="T_gt"):
        edge_diagnostics([frame], Fixed2D(), All3D())
