"""DeepI2P's official size around the authors' network (whose tensors tests/test_deepi2p_reference.py proves): the
importer of their state-dict layout, the cell geometry that lets EPnP-RANSAC on full-size pixels run their
solve_PnP, their inference rule, and the size run end to end on a real KITTI frame."""

from __future__ import annotations

import hashlib
import json
import types
import zlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from i2pbench_deepi2p.official import importer, solvers
from i2pbench_deepi2p.official.network import DeepI2PNetwork
from i2pbench_deepi2p.official.stages import (
    LIDAR_TO_CAMERA_AXES,
    OfficialFrustum,
    OfficialPnP,
    cell_pixels,
    classified_matches,
    crop_K,
    pixel_cells,
    projects_inside,
)

from i2pbench.api import Keypoints2D, Matches, WeightsError
from i2pbench.cli import main
from i2pbench.registry.build import default_registry
from i2pbench.runs.store import ResultsStore
from i2pbench.testing.recipe import recipe_value
from i2pbench.weights.checkpoints import load_checkpoint

SHAPES = Path(__file__).parent / "data" / "reference" / "deepi2p" / "state_dict_shapes.json"
# KITTI's camera 2 (sequence 00) and a 1241 x 376 image: rows below the top 50 halved to 620 x 163, crop offsets
# dx = (620 - 512) // 2 = 54, dy = (163 - 160) // 2 = 1
K = np.array([[718.856, 0, 607.1928], [0, 718.856, 185.2157], [0, 0, 1]])
WIDTH, HEIGHT = 1241, 376


@pytest.fixture(scope="module")
def authors_state() -> dict[str, torch.Tensor]:
    """a seeded state dict in the authors' layout as DataParallel saves it (`module.` before every key)."""
    shapes = json.loads(SHAPES.read_text())
    return {f"module.{k}": torch.from_numpy(recipe_value(k, tuple(s), "/import")) for k, s in shapes.items()}


def test_import_round_trips_the_authors_state_dict(authors_state, tmp_path):
    source = tmp_path / "model_kitti.pth"
    torch.save(authors_state, source)
    out = tmp_path / "W.pt"
    assert main(["weights", "import", "deepi2p-official", str(source), "--out", str(out)]) == 0
    checkpoint = load_checkpoint(out)
    state = checkpoint.state["matcher"]
    assert len(state) == len(authors_state) - 2  # all but the ResNet's unused ImageNet fc (weight, bias)
    for key, value in authors_state.items():
        if ".fc." not in key:
            assert torch.equal(state["net." + key.removeprefix("module.")], value), key
    origin = checkpoint.meta["imported_from"]
    assert origin["importer"] == "deepi2p-official" and origin["file"] == "model_kitti.pth"
    assert origin["sha256"] == hashlib.sha256(source.read_bytes()).hexdigest()
    assert origin["dropped"] == ["img_encoder.backbone.fc.bias", "img_encoder.backbone.fc.weight"]
    trained_on = str(checkpoint.trained_on)
    assert "user-supplied" in trained_on and "issue #2" in trained_on and "Oxford" in trained_on


def test_import_refuses_a_key_that_does_not_fit_by_name(authors_state, tmp_path):
    state = dict(authors_state)
    state["module.pc_encoder.extra_pointnet.layers.0.conv.weight"] = torch.zeros(1)
    state["module.node_a_pn.layers.0.conv.weight"] = state["module.node_a_pn.layers.0.conv.weight"][:, :10]
    del state["module.per_point_pn.layers.1.norm.running_var"]
    torch.save(state, tmp_path / "bad.pth")
    with pytest.raises(
        WeightsError, match=r"unexpected key pc_encoder\.extra_pointnet\.layers\.0\.conv\.weight"
    ) as err:
        importer.import_official(tmp_path / "bad.pth")
    assert "missing key per_point_pn.layers.1.norm.running_var" in str(err.value)
    assert "key node_a_pn.layers.0.conv.weight: shape (512, 10, 1), expected (512, 832, 1)" in str(err.value)
    assert main(["weights", "import", "deepi2p-official", str(tmp_path / "bad.pth"), "--out", str(tmp_path / "W.pt")])
    assert not (tmp_path / "W.pt").exists()


def test_the_authors_oxford_release_is_refused_for_the_kitti_input_by_its_fine_head(tmp_path):
    oxford = {"module." + k: v for k, v in DeepI2PNetwork((384, 640)).state_dict().items()}
    torch.save(oxford, tmp_path / "oxford.pth")
    with pytest.raises(WeightsError, match=r"per_point_pn\.layers\.2\.conv\.weight: shape \(242, 256, 1\), expected"):
        importer.import_official(tmp_path / "oxford.pth")


def kitti_crop_K() -> np.ndarray:
    """K of the authors' 160 x 512 crop: top 50 rows cut, halved, shifted by the crop offsets (54, 1)."""
    crop = K.copy()
    crop[1, 2] -= 50
    crop = 0.5 * crop
    crop[2, 2] = 1
    crop[0, 2] -= 54
    crop[1, 2] -= 1
    return crop


def test_crop_K_moves_the_frames_K_as_the_authors_loader():
    np.testing.assert_allclose(crop_K(K, WIDTH, HEIGHT, {"top_rows": 50, "scale": 0.5, "crop": (512, 160)}),
                               kitti_crop_K(), atol=1e-12)  # fmt: skip


def test_cell_pixels_are_the_authors_cell_corners_under_the_frames_K():
    uv = cell_pixels(WIDTH, HEIGHT)
    assert uv.shape == (5 * 16, 2)  # 32 px cells of the 160 x 512 crop
    # cell (c, r) at u = 64 c + 2 * 54, v = 64 r + 2 * 1 + 50
    np.testing.assert_array_equal(uv[[0, 1, 16, 79]], [[108, 52], [172, 52], [108, 116], [1068, 308]])
    np.testing.assert_array_equal(pixel_cells(uv + 63.9, WIDTH, HEIGHT), np.arange(80))  # anywhere in its cell
    np.testing.assert_array_equal(pixel_cells(np.array([[107.0, 52], [108, 51], [1132, 52]]), WIDTH, HEIGHT), -1)
    assert len(cell_pixels(160, 96)) == 0  # a frame too small for the authors' crop has no pixel
    # the authors' PnP reads cell (c, r) as the pixel (c, r) under K/32 of the crop; the same point under the frame's
    # K lands on 64 (c, r) + (108, 52)
    K32 = kitti_crop_K() / 32
    K32[2, 2] = 1
    points = np.random.default_rng(0).uniform([-10, -2, 5], [10, 2, 40], (50, 3))
    cells = (points @ K32.T)[:, :2] / points[:, 2:]
    np.testing.assert_allclose((points @ K.T)[:, :2] / points[:, 2:], 64 * cells + [108, 52], atol=1e-9)


def frame_stub() -> types.SimpleNamespace:
    return types.SimpleNamespace(K=K, image_size=(WIDTH, HEIGHT), inputs="")


def test_the_solver_is_the_authors_solve_pnp_on_cells():
    """classifier outputs of a scene 8 m ahead, yawed 20 deg: every point's true cell, and 30% of the inside points
    given a wrong one; their solve_PnP (cell units, K/32 of the crop, 0.6) and ours (full-size corner pixels, the
    frame's K, 38.4 px) reach the same pose and inliers."""
    rng = np.random.default_rng(3)
    yaw = np.deg2rad(20)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]]
    T[:3, 3] = [0.5, -0.3, 8.0]
    points = rng.uniform([-15, -2, -15], [15, 2, 25], (3000, 3))
    camera = points @ T[:3, :3].T + T[:3, 3]
    projected = (camera @ kitti_crop_K().T)[:, :2] / camera[:, 2:]
    inside = (camera[:, 2] > 0.1) & (projected >= 0).all(1) & (projected[:, 0] <= 511) & (projected[:, 1] <= 159)
    cell = (np.floor(projected[:, 1] / 32) * 16 + np.floor(projected[:, 0] / 32)).astype(np.int64)
    wrong = inside & (rng.random(len(points)) < 0.3)
    cell[wrong] = rng.integers(0, 80, wrong.sum())
    theirs, outliers = solvers.solve_pnp(points.T, inside.astype(np.int64), cell, kitti_crop_K(), (160, 512))
    kp2d = Keypoints2D(cell_pixels(WIDTH, HEIGHT))
    matches = Matches(cell[inside], np.flatnonzero(inside), np.ones(inside.sum(), np.float32))
    kp3d = types.SimpleNamespace(xyz=points)  # float64, as their solver reads the points
    ours = OfficialPnP()(frame_stub(), kp2d, kp3d, matches)
    assert ours.ok and 0.2 < outliers < 0.5
    np.testing.assert_allclose(ours.T, theirs, atol=1e-6)
    assert len(ours.inliers) == round((1 - outliers) * inside.sum())
    np.testing.assert_allclose(theirs[:3, 3], T[:3, 3], atol=1.0)  # a right pose, as 70% true cells allow


def test_the_solver_refuses_a_translation_of_14_14_m_or_more():
    points = np.random.default_rng(1).uniform([-5, -1, 10], [5, 1, 30], (40, 3))
    for offset, ok in ((np.array([0.0, 0.0, 5.0]), True), (np.array([12.0, 0.0, 10.0]), False)):
        camera = points + offset
        uv = (camera @ K.T)[:, :2] / camera[:, 2:]
        matches = Matches(np.arange(40), np.arange(40), np.ones(40, np.float32))
        estimate = OfficialPnP()(frame_stub(), Keypoints2D(uv), types.SimpleNamespace(xyz=points), matches)
        assert estimate.ok is ok, estimate.message
        if ok:
            np.testing.assert_allclose(estimate.T[:3, 3], offset, atol=1e-6)
        else:
            assert "translation 15.62 m >= 14.14 m" in estimate.message
    few = OfficialPnP()(frame_stub(), Keypoints2D(uv), types.SimpleNamespace(xyz=points), Matches.empty())
    assert not few.ok and "0 points classified inside, EPnP needs 4" in few.message


def test_the_matcher_pairs_each_point_classified_inside_with_its_predicted_cell():
    # 4 points, 3 cells; keypoints: cell 2, cell 0, cell 2 again, outside the crop
    coarse = torch.tensor([[0.0, 1.0, 2.0, 0.0], [1.0, 0.0, 1.0, 1.0]])  # inside: points 0 and 3 (1 > 0)
    fine = torch.tensor([[0.0, 0, 0, 2], [0, 0, 0, 0], [2, 0, 0, 0]])  # argmax: point 0 -> cell 2, point 3 -> cell 0
    matches = classified_matches(coarse, fine, np.array([2, 0, 2, -1]), 90.5)
    np.testing.assert_array_equal(matches.index3d, [0, 3])
    np.testing.assert_array_equal(matches.index2d, [0, 1])  # the first keypoint of cell 2; cell 0's
    e2 = np.exp(2.0)
    np.testing.assert_allclose(matches.score, [e2 / (e2 + 2), e2 / (e2 + 2)], rtol=1e-6)
    e = np.exp(1.0)
    np.testing.assert_allclose(matches.frustum, [e / (e + 1), 1 / (1 + e), 1 / (1 + e), e / (e + 1)], rtol=1e-6)
    assert matches.radius_px == 90.5
    # a point whose cell has no keypoint gets no pair (its frustum score stands)
    alone = classified_matches(coarse, fine, np.array([0, -1]), 90.5)
    np.testing.assert_array_equal(alone.index3d, [3])


def test_the_official_size_runs_the_authors_stages():
    (row,) = default_registry().preset_rows("deepi2p-official")
    assert row["matcher"] == "deepi2p-official" and row["encoder2d"] == row["encoder3d"] == row["exchanger"] == "none"
    assert row["extractor2d"] == "deepi2p-official-grid" and row["extractor3d"] == "deepi2p-official-points"
    assert row["solver"] == "deepi2p-official-pnp"
    assert default_registry().component("solver", "deepi2p-official-frustum").name == "deepi2p-official-frustum"
    assert OfficialPnP().conf == {"iterations": 500, "reprojection_error_px": 38.4, "max_translation_m": 14.14}


def test_the_preset_runs_untrained_on_a_real_kitti_frame_and_says_so(shared_data, tmp_path):
    out = tmp_path / "board"
    argv = ["run", "--preset", "deepi2p-official", "--dataset", "kitti", "--split", "all", "--data-root",
            str(shared_data / "kitti_odometry"), "--frames", "1", "--weights", "untrained", "--runs-dir",
            str(tmp_path / "runs"), "--out", str(out), "--threads", "1", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    (record,) = ResultsStore(tmp_path / "runs" / "kitti-all").load().itertuples()
    assert record.weights == "untrained" and record.weights_trained_on == ""
    assert (record.n_kp2d, record.n_kp3d) == (80, 20480)  # the authors' 80 cells and 20,480 points
    board = pd.read_csv(out.with_suffix(".csv")).iloc[0]
    assert board["weights"] == "untrained" and board["frames"] == 1
    if record.status == "failed":  # an untrained classifier: too few points classified inside for EPnP
        assert record.error.startswith("solver 'deepi2p-official-pnp'") and board["failures"] == 1
    else:  # a pose from an untrained network: a success without true pairs is counted as luck, not skill
        assert record.T_pred is not None and np.isfinite(record.rte_m)
        if record.n_true_matches == 0:
            assert board["Acc. with true matches (%) ↑"] == 0.0


def test_the_frustum_solver_finds_the_pose_from_true_frustum_labels_as_their_solver_does():
    """4,000 points of a street box, camera 8 deg yawed and 2 m ahead of the LiDAR; frustum scores 0.9 inside the
    crop's view, 0.1 outside: the 2D frustum registration from 8 seeded restarts is their solve_frustum on the cloud
    in camera axes with the crop's K, and lands within 0.5 m and 1 deg (measured: 2.8 cm, 0.11 deg)."""
    rng = np.random.default_rng(5)
    points = rng.uniform([-30, -20, -1.7], [40, 20, 3], (4000, 3))
    yaw = np.deg2rad(8)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]] @ LIDAR_TO_CAMERA_AXES
    T[:3, 3] = [0.5, 0.0, 2.0]
    inside = projects_inside(points, T, kitti_crop_K(), (160, 512))
    frustum = np.where(inside, 0.9, 0.1).astype(np.float32)
    frame = types.SimpleNamespace(K=K, image_size=(WIDTH, HEIGHT), dataset="toy", frame_id="street", inputs="")
    matches = Matches(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32), frustum)
    estimate = OfficialFrustum({"restarts": 8})(frame, None, types.SimpleNamespace(xyz=points), matches)
    assert estimate.ok
    pc = (points @ LIDAR_TO_CAMERA_AXES.T).T
    yaw0, _ = solvers.initial_guess(pc, inside.astype(np.int64))
    starts = solvers.restarts(yaw0, np.random.default_rng(zlib.crc32(b"toy/street")), 8)
    theirs, _ = solvers.solve_frustum(pc, inside.astype(np.int64), kitti_crop_K(), (160, 512), starts)
    np.testing.assert_allclose(estimate.T[:3, :3], theirs[:3, :3] @ LIDAR_TO_CAMERA_AXES, atol=1e-12)
    np.testing.assert_allclose(estimate.T[:3, 3], theirs[:3, 3], atol=1e-12)
    assert np.linalg.norm(estimate.T[:3, 3] - T[:3, 3]) < 0.5
    cos = (np.trace(estimate.T[:3, :3].T @ T[:3, :3]) - 1) / 2
    assert np.degrees(np.arccos(min(cos, 1.0))) < 1.0
    nothing = Matches(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32), 0 * frustum)
    refused = OfficialFrustum()(frame, None, types.SimpleNamespace(xyz=points), nothing)
    assert not refused.ok and "no point classified inside" in refused.message
