"""A card's inputs made from a dataset's frame (i2pbench.scoring.protocol_inputs): the peers' resize and centre crop
with K, their voxel grid and point sampling, and poses drawn in the camera frame; values worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from i2pbench.geometry.transforms import invert, transform_points
from i2pbench.scoring import installed
from i2pbench.scoring.protocol import Protocol
from i2pbench.scoring.protocol_inputs import image_geometry, sample, transform_K, voxel_means
from i2pbench.types import SensorFrame

K = np.array([[700.0, 0.0, 620.0], [0.0, 700.0, 188.0], [0.0, 0.0, 1.0]])
T_CL = np.array([[0.0, -1.0, 0.0, 0.06], [0.0, 0.0, -1.0, -0.08], [1.0, 0.0, 0.0, -0.27], [0.0, 0.0, 0.0, 1.0]])


def frame(points: np.ndarray) -> SensorFrame:
    return SensorFrame("kitti", "00/000000", np.zeros((376, 1241, 3), np.uint8), points.astype(np.float32),
                       np.arange(len(points), dtype=np.int16), K, T_CL)  # fmt: skip


def test_resize_then_centre_crop_as_the_peers_loaders():
    # 1241 x 376 halves to round(620.5) = 620 (Python rounds half to even, as their int(round())) x 188; the
    # 512 x 160 crop starts at int(108 / 2) = 54, int(28 / 2) = 14
    assert image_geometry((376, 1241, 3), 0, 0.5, (160, 512)) == ((620, 188), (54, 14))
    assert transform_K(K, 0, 0.5, (54, 14)).tolist() == [[350.0, 0.0, 256.0], [0.0, 350.0, 80.0], [0.0, 0.0, 1.0]]
    # DeepI2P cuts 50 rows first: 326 rows halve to 163, crop at int(3 / 2) = 1; cy = (188 - 50) / 2 - 1 = 68
    assert image_geometry((376, 1241, 3), 50, 0.5, (160, 512)) == ((620, 163), (54, 1))
    assert transform_K(K, 50, 0.5, (54, 1))[1, 2] == 68.0


def test_a_point_projects_where_the_resized_cropped_image_shows_it():
    xyz = np.array([[12.0, 1.5, -0.4], [20.0, -3.0, 0.5], [8.0, 0.2, 0.1]])
    sensor = frame(np.c_[xyz, np.full(3, 0.5)])
    p = installed.find("corri2p").protocol(seed=4, dataset="kitti")
    got = p.apply(sensor)
    assert got.image.shape == (160, 512, 3) and len(got.points) == 40960  # 3 points, each repeated
    cam = transform_points(T_CL, xyz)
    uv = (K @ cam.T).T
    expected = np.c_[uv[:, 0] / uv[:, 2] * 0.5 - 54, uv[:, 1] / uv[:, 2] * 0.5 - 14]
    seen = transform_points(got.T_gt, got.points[:, :3].astype(np.float64))
    proj = (got.K @ seen.T).T
    unique = np.unique(np.round(proj[:, :2] / proj[:, 2:], 3), axis=0)
    assert np.allclose(np.sort(unique, axis=0), np.sort(expected, axis=0), atol=1e-3)


def test_camera_frame_poses_move_the_cloud_in_the_camera_frame():
    xyz = np.array([[12.0, 1.5, -0.4], [20.0, -3.0, 0.5]])
    p = Protocol(seed=2, pose_frame="camera")
    got = p.apply(frame(np.c_[xyz, np.full(2, 0.5)]))
    T_rand = p.random_transform("kitti", "00/000000")
    assert T_rand[1].tolist() == [0.0, 1.0, 0.0, 0.0]  # a yaw about camera y, no vertical translation
    assert np.allclose(got.T_gt, invert(T_rand)) and np.array_equal(got.T_init, np.eye(4))
    assert np.allclose(got.points[:, :3], transform_points(T_rand @ T_CL, xyz), atol=1e-5)
    assert np.allclose(got.ranges, np.linalg.norm(xyz, axis=1))  # as measured, never moved


def test_voxel_means_keep_scan_order_and_the_first_points_ring():
    points = np.array([[0.01, 0.01, 0.01, 0.2], [0.25, 0.0, 0.0, 1.0], [0.05, 0.02, 0.03, 0.4],
                       [0.07, 0.08, 0.09, 0.6]], np.float32)  # fmt: skip
    # the grid starts half a voxel below the minimum (0.01, 0, 0): at (-0.04, -0.05, -0.05), so the rows fall in
    # voxels (0, 0, 0), (2, 0, 0), (0, 0, 0) and (1, 1, 1)
    means, ring = voxel_means(points, np.array([7, 8, 9, 10], np.int16), 0.1)
    assert ring.tolist() == [7, 8, 10]  # in the order of each voxel's first row
    assert means[0] == pytest.approx([0.03, 0.015, 0.02, 0.3], abs=1e-6)
    assert means[1] == pytest.approx([0.25, 0.0, 0.0, 1.0], abs=1e-7)
    assert means[2] == pytest.approx([0.07, 0.08, 0.09, 0.6], abs=1e-7)


def test_sampling_draws_without_replacement_or_repeats_every_point():
    rng = np.random.default_rng(0)
    drawn = sample(5, 3, rng)
    assert len(set(drawn.tolist())) == 3 and drawn.tolist() == sorted(drawn.tolist())
    repeated = sample(2, 5, rng)  # both points twice, one of them a third time
    assert sorted(np.bincount(repeated).tolist()) == [2, 3]


def test_the_default_protocol_gives_the_datasets_frame_untouched():
    xyz = np.array([[12.0, 1.5, -0.4], [20.0, -3.0, 0.5]])
    got = Protocol().apply(frame(np.c_[xyz, np.full(2, 0.5)]))
    assert got.image.shape == (376, 1241, 3) and np.array_equal(got.K, K) and len(got.points) == 2
    assert np.array_equal(got.T_init, T_CL) and got.K_gt is None
