import subprocess
import sys

import numpy as np
import pytest

from i2pbench.errors import DataError
from i2pbench.geometry.transforms import invert, transform_points
from i2pbench.scoring.protocol import Protocol
from i2pbench.types import SensorFrame

SNIPPET = (
    "from i2pbench.scoring.protocol import Protocol; "
    "print(Protocol(seed=7).random_transform('kitti', '00/000003').tolist())"
)


def test_transforms_are_identical_across_processes():
    outputs = {
        subprocess.run([sys.executable, "-c", SNIPPET], capture_output=True, text=True, check=True).stdout
        for _ in range(2)
    }
    assert len(outputs) == 1
    assert np.allclose(np.array(eval(outputs.pop())), Protocol(seed=7).random_transform("kitti", "00/000003"))


def test_transform_does_not_depend_on_order_or_other_frames():
    p = Protocol(seed=3)
    ids = [f"00/{i:06d}" for i in range(20)]
    forward = {i: p.random_transform("kitti", i) for i in ids}
    backward = {i: p.random_transform("kitti", i) for i in reversed(ids[5:])}
    for i in backward:
        assert np.array_equal(forward[i], backward[i])
    assert not np.allclose(forward[ids[0]], forward[ids[1]])
    assert not np.allclose(p.random_transform("nuscenes", ids[0]), forward[ids[0]])
    assert not np.allclose(Protocol(seed=4).random_transform("kitti", ids[0]), forward[ids[0]])


def test_transform_is_a_yaw_and_planar_translation_within_range():
    p = Protocol()
    for i in range(200):
        T = p.random_transform("synthetic", str(i))
        assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3))
        assert np.allclose(T[2, :3], [0, 0, 1]) and T[2, 3] == 0.0
        assert np.all(np.abs(T[:2, 3]) <= 10.0)


def test_ground_truth_maps_moved_points_back_onto_the_camera():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(50, 4)).astype(np.float32)
    T_cam_lidar = np.eye(4)
    T_cam_lidar[:3, 3] = [0.1, -0.2, 0.3]
    sensor = SensorFrame(
        "kitti", "00/000001", np.zeros((4, 4, 3), np.uint8), points, np.zeros(50, np.int16), np.eye(3), T_cam_lidar
    )
    frame = Protocol().apply(sensor)
    expected = transform_points(T_cam_lidar, points[:, :3].astype(np.float64))
    assert np.allclose(transform_points(frame.T_gt, frame.points[:, :3].astype(np.float64)), expected, atol=1e-4)
    assert np.allclose(frame.ranges, np.linalg.norm(points[:, :3], axis=1), atol=1e-6)
    assert np.allclose(frame.T_gt, T_cam_lidar @ invert(Protocol().random_transform("kitti", "00/000001")))
    assert np.array_equal(frame.points[:, 3], points[:, 3])


def test_card_records_every_parameter_and_identity_changes_with_them():
    card = Protocol().card()
    assert card["acc_rre_deg"] == 5.0 and card["acc_rte_m"] == 2.0
    assert card["filter_rre_deg"] == 10.0 and card["filter_rte_m"] == 5.0
    assert card["translation_range_m"] == 10.0 and card["rotation_range_rad"] == pytest.approx(2 * np.pi)
    assert Protocol().identity() != Protocol(seed=1).identity()


def test_a_scan_with_nan_points_is_refused_naming_its_source():
    points = np.zeros((3, 4), np.float32)
    points[1, 2] = np.nan
    sensor = SensorFrame(
        "kitti",
        "00/000002",
        np.zeros((4, 4, 3), np.uint8),
        points,
        np.zeros(3, np.int16),
        np.eye(3),
        np.eye(4),
        source="/data/00/velodyne/000002.bin",
    )
    with pytest.raises(DataError, match="/data/00/velodyne/000002.bin: the scan contains NaN"):
        Protocol().apply(sensor)
