"""What counts as a true match, by hand: a LiDAR point projecting within eps_c pixels of its pixel, in front."""

import numpy as np
import pytest

from i2pbench.geometry.correspondence import true_match_mask
from i2pbench.geometry.transforms import make_transform, rot_z
from i2pbench.types import Frame

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])


def frame(T_gt) -> Frame:
    points = np.zeros((1, 4), np.float32)
    return Frame("toy", "f", np.zeros((480, 640, 3), np.uint8), points, np.zeros(1, np.int16), np.ones(1), K, T_gt)


def test_pairs_within_eps_c_in_front_of_the_camera_are_true():
    f = frame(np.eye(4))
    xyz = np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 10.0], [1.0, 0.0, 10.0], [0.0, 0.0, -10.0]])
    # projections: (320, 240), (320, 240), (370, 240) since 500 * 1 / 10 = 50, and the last is behind the camera
    uv = np.array([[322.9, 240.0], [323.0, 240.0], [370.0, 242.0], [320.0, 240.0]])
    assert true_match_mask(f, uv, xyz).tolist() == [True, False, True, False]  # 2.9 < 3; 3.0 is not; 2 px
    assert true_match_mask(f, uv, xyz, radius_px=5.0).tolist() == [True, True, True, False]


def test_the_pose_is_the_ground_truth_one():
    T = make_transform(rot_z(np.pi / 2), np.array([0.0, 0.0, 0.0]))  # LiDAR x -> camera y
    xyz = np.array([[0.0, -1.0, 10.0]])  # rot_z(90°) maps (0, -1, 10) to (1, 0, 10): pixel (370, 240)
    assert true_match_mask(frame(T), np.array([[370.0, 240.0]]), xyz).tolist() == [True]
    assert true_match_mask(frame(np.eye(4)), np.array([[370.0, 240.0]]), xyz).tolist() == [False]


def test_needs_ground_truth():
    with pytest.raises(ValueError, match="T_gt"):
        true_match_mask(frame(None), np.zeros((1, 2)), np.zeros((1, 3)))
