"""PnP solvers on synthetic correspondences: exact data gives the exact pose; outliers are rejected; degenerate or
too-small inputs give a failed estimate, never an exception."""

from __future__ import annotations

import numpy as np
import pytest
from i2pbench_classic.solvers import EPnPRansacSolver, PoseLibSolver
from scipy.spatial.transform import Rotation

from i2pbench.geometry.transforms import make_transform, project
from i2pbench.scoring.pose import pose_errors
from i2pbench.types import Frame, Keypoints2D, Keypoints3D, Matches

K = np.array([[721.5377, 0.0, 609.5593], [0.0, 721.5377, 172.854], [0.0, 0.0, 1.0]])
SOLVERS = [EPnPRansacSolver, PoseLibSolver]
# How exact "exact" is. PoseLib works in float64 (max |T - T_true| 1.8e-15). OpenCV's solvePnPRansac copies the points
# to float32, so EPnP recovers the pose only to float32 precision, and which way each coordinate rounds decides the
# figure: 3.1e-7 on the 200 exact matches and 8.5e-7 on the 80 reversed ones (float32-rounded inputs give the same
# pose bit for bit). Moving the pixels by a relative 1e-8, below float32's resolution, took the 80-match case over the
# former 1e-6 tolerance in 33% of 200 tries (up to 2.6e-6); moves of 3e-8 gave up to 4.8e-6. Faults stay far outside
# 5e-5: a principal point half a pixel off moves T by 2.2e-3, a focal length 0.1% off by 1.7e-2.
EXACT_ATOL = {EPnPRansacSolver: 5e-5, PoseLibSolver: 1e-6}


def problem(n=200, outliers=0.0, seed=0):
    """(frame, kp2d, kp3d, matches, T_true, outlier mask): LiDAR points 5-40 m in front of a camera at a random pose."""
    rng = np.random.default_rng(seed)
    T = make_transform(Rotation.from_euler("xyz", [-90, 3, -80], degrees=True).as_matrix(), [0.3, -1.2, 4.0])
    cam = np.column_stack([rng.uniform(-10, 10, n), rng.uniform(-2, 2, n), rng.uniform(5, 40, n)])
    xyz = (cam - T[:3, 3]) @ T[:3, :3]  # LiDAR coordinates: T maps them back to `cam`
    uv, _ = project(K, T, xyz)
    bad = rng.random(n) < outliers
    uv[bad] = rng.uniform([0, 0], [1242, 375], size=(int(bad.sum()), 2))
    points = np.column_stack([xyz, np.zeros(n)]).astype(np.float32)
    frame = Frame(
        "toy",
        "f",
        np.zeros((375, 1242, 3), np.uint8),
        points,
        np.zeros(n, np.int16),
        np.linalg.norm(xyz, axis=1).astype(np.float32),
        K,
        None,
    )
    kp3d = Keypoints3D(np.arange(n), xyz, np.zeros(n, np.float32))  # float64 xyz (OpenCV still rounds to float32)
    idx = np.arange(n)
    return frame, Keypoints2D(uv.astype(np.float64)), kp3d, Matches(idx, idx, np.ones(n, np.float32)), T, bad


@pytest.mark.parametrize("cls", SOLVERS)
def test_exact_correspondences_give_the_exact_pose(cls):
    frame, kp2d, kp3d, matches, T, _ = problem()
    est = cls()(frame, kp2d, kp3d, matches)
    assert est.ok
    np.testing.assert_allclose(est.T, T, atol=EXACT_ATOL[cls])
    assert len(est.inliers) == 200


@pytest.mark.parametrize("cls", SOLVERS)
def test_outliers_are_rejected(cls):
    frame, kp2d, kp3d, matches, T, bad = problem(n=300, outliers=0.5, seed=1)
    est = cls()(frame, kp2d, kp3d, matches)
    err = pose_errors(est.T, T)
    assert err.rre_deg < 1e-4 and err.rte_m < 1e-4
    inliers = np.zeros(300, bool)
    inliers[est.inliers] = True
    assert np.all(inliers[~bad])  # every true correspondence is kept
    assert inliers[bad].mean() < 0.05  # a random pixel lands within 6.5 px of the true projection rarely


@pytest.mark.parametrize("cls", SOLVERS)
@pytest.mark.parametrize("n", [0, 1, 3])
def test_too_few_matches_fail_without_exception(cls, n):
    frame, kp2d, kp3d, _, _, _ = problem()
    idx = np.arange(n)
    est = cls()(frame, kp2d, kp3d, Matches(idx, idx, np.ones(n, np.float32)))
    assert not est.ok and "at least 4" in est.message


@pytest.mark.parametrize("cls", SOLVERS)
def test_collinear_points_are_degenerate(cls):
    frame, kp2d, kp3d, matches, _, _ = problem(n=10)
    t = np.linspace(0, 1, 10)[:, None]
    line = Keypoints3D(kp3d.index, np.array([1.0, 2.0, 10.0]) + t * np.array([1.0, 0.5, 3.0]), kp3d.reflectance)
    est = cls()(frame, kp2d, line, matches)
    assert not est.ok and "degenerate" in est.message


@pytest.mark.parametrize("cls", SOLVERS)
def test_pure_noise_does_not_raise(cls):
    frame, kp2d, kp3d, matches, _, _ = problem(n=50, outliers=1.0, seed=3)
    est = cls({"max_iterations": 2000} if cls is PoseLibSolver else {"iterations": 500})(frame, kp2d, kp3d, matches)
    assert est.ok or est.message  # either answer is allowed; an exception is not


@pytest.mark.parametrize("cls", SOLVERS)
def test_solvers_are_deterministic(cls):
    frame, kp2d, kp3d, matches, _, _ = problem(n=300, outliers=0.7, seed=2)
    a, b = cls()(frame, kp2d, kp3d, matches), cls()(frame, kp2d, kp3d, matches)
    np.testing.assert_array_equal(a.T, b.T)
    np.testing.assert_array_equal(a.inliers, b.inliers)


def test_inliers_index_the_matches_not_the_keypoints():
    frame, kp2d, kp3d, _, T, _ = problem(n=100)
    rows = np.arange(99, 19, -1)  # matches list keypoints 99..20 in reverse
    est = EPnPRansacSolver()(frame, kp2d, kp3d, Matches(rows, rows, np.ones(80, np.float32)))
    assert sorted(est.inliers.tolist()) == list(range(80))
    np.testing.assert_allclose(est.T, T, atol=EXACT_ATOL[EPnPRansacSolver])
