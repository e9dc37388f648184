"""CoFiI2P's official size around the authors' network (whose tensors tests/test_cofii2p_reference.py proves): the
loader's preparation, the fine-map geometry, eval_all.py's fine matching and solvePnPRansac, the size's declaration,
an untrained KITTI frame end to end under the cofii2p card, and the authors' layout imported through the command and
run by the preset under the default card."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from i2pbench_cofii2p.official.matching import cell_rows, fine_pixels, node_rows
from i2pbench_cofii2p.official.prepare import CROP, loader_cloud, loader_crop, loader_draw, network_axes, network_inputs
from i2pbench_cofii2p.official.solver import OfficialPnP, fine_camera, fine_coordinates
from i2pbench_cofii2p.official.stages import OfficialCoFiI2P, OfficialGrid, fine_cells, grid_pixels

from i2pbench.api import Frame, Keypoints2D, Keypoints3D, Matches, make_transform
from i2pbench.boards import leaderboard
from i2pbench.cli import main
from i2pbench.layers.point_pyramid import PointPyramid
from i2pbench.registry.build import default_registry
from i2pbench.testing.recipe import recipe_state

K = np.array([[718.856, 0, 607.1928], [0, 718.856, 185.2157], [0, 0, 1]])


def frame(width: int = 1242, height: int = 375, points: np.ndarray | None = None, T_init=None, inputs="") -> Frame:
    """a frame of the dataset (`inputs` "") or one the `cofii2p` card built (`inputs` "cofii2p")."""
    points = np.zeros((0, 4), np.float32) if points is None else points
    return Frame("test", "0", np.zeros((height, width, 3), np.uint8), points, np.zeros(len(points), np.int16),
                 np.ones(len(points), np.float32), K, None, T_init=T_init, inputs=inputs)  # fmt: skip


def test_grid_pixels_are_the_fine_map_cells_under_the_frames_K():
    # a 1242 x 375 image halved to 621 x 188 (int(round(187.5)) = 188), crop offsets dx = int((621 - 512) / 2) = 54,
    # dy = int((188 - 160) / 2) = 14, no rows cut (data/kitti.py:306-320); fine cell (x, y) of the 256 x 80 map at
    # u = 4x + 108, v = 4y + 28
    uv = grid_pixels(1242, 375)
    assert uv.shape == (80 * 256, 2)
    np.testing.assert_array_equal(uv[[0, 1, 256, -1]], [[108, 28], [112, 28], [108, 32], [1128, 344]])
    np.testing.assert_array_equal(fine_cells(uv + 3.9, 1242, 375), np.arange(len(uv)))
    # their K_2: K x 0.5, minus the offsets, x 0.5 (data/kitti.py:310,320,325)
    crop = {"top_rows": 0, "scale": 0.5, "crop": (512, 160)}
    K2 = fine_camera(K, 1242, 375, crop)
    np.testing.assert_allclose(K2, [[179.714, 0, 124.7982], [0, 179.714, 39.303925], [0, 0, 1]], rtol=1e-6)
    # with DeepI2P's cut of 50 rows (`top_rows`): 325 rows halved to 162 (round(162.5) = 162), dy = 1, v = 4y + 52
    cut = {**crop, "top_rows": 50}
    np.testing.assert_array_equal(grid_pixels(1242, 375, cut)[[0, -1]], [[108, 52], [1128, 368]])
    np.testing.assert_allclose(fine_camera(K, 1242, 375, cut)[1, 2], (185.2157 - 50) / 4 - 0.5, rtol=1e-6)
    points = np.random.default_rng(0).uniform([-10, -2, 5], [10, 2, 40], (50, 3))
    fine = (points @ K2.astype(np.float64).T)[:, :2] / points[:, 2:]
    full = (points @ K.T)[:, :2] / points[:, 2:]
    np.testing.assert_allclose(full, 4 * fine + [108, 28], atol=1e-4)  # K_2 holds K in float32
    np.testing.assert_allclose(fine_coordinates(full, 1242, 375, crop), fine, atol=1e-4)
    # the grid's own pixels map back to their cells' integer (x, y) exactly: the coordinates the authors' PnP reads
    cols, rows = np.meshgrid(np.arange(256), np.arange(80))
    np.testing.assert_array_equal(fine_coordinates(uv, 1242, 375, crop), np.column_stack([cols.ravel(), rows.ravel()]))


def test_a_frame_the_cofii2p_card_built_is_taken_as_it_is():
    # the card hands the loader's 160 x 512 crop and its K: the grid is then the crop's stride-2 cells, u = 2x
    assert loader_crop(512, 160, {"top_rows": 50, "scale": 0.5, "crop": (512, 160)}) == {
        "top_rows": 0,
        "scale": 1.0,
        "crop": (512, 160),
    }
    uv = OfficialGrid()(frame(512, 160)).uv
    np.testing.assert_array_equal(uv[[0, 1, 256]], [[0, 0], [2, 0], [0, 2]])
    np.testing.assert_allclose(fine_camera(K, 512, 160, {"top_rows": 50, "scale": 0.5, "crop": (512, 160)}),
                               K * [[.5], [.5], [1]], rtol=1e-6)  # fmt: skip
    cloud = np.random.default_rng(1).uniform(-20, 20, (2048, 4)).astype(np.float32)
    kp3d = loader_cloud(frame(512, 160, cloud, np.eye(4), inputs="cofii2p"), 2048, 0)
    np.testing.assert_array_equal(kp3d.index, np.arange(2048))  # its points, in the card's draw order
    np.testing.assert_array_equal(kp3d.xyz, cloud[:, :3])


def test_the_loader_draw_repeats_every_point_before_drawing_the_rest():
    state = np.random.RandomState(5)
    drawn = loader_draw(3, 8, state)
    # 3 points into 8: all of them twice (while 3 + 6 >= 8 stops the repeats), then 2 drawn without repeats
    np.testing.assert_array_equal(drawn[:6], [0, 1, 2, 0, 1, 2])
    np.testing.assert_array_equal(drawn[6:], np.random.RandomState(5).choice(3, 2, replace=False))
    assert sorted(loader_draw(10, 4, np.random.RandomState(0))) == sorted(
        np.random.RandomState(0).choice(10, 4, replace=False)
    )


def test_the_cloud_meets_the_network_in_camera_axes_with_up_normals():
    rng = np.random.default_rng(2)
    ground = np.column_stack([rng.uniform(-5, 5, (8000, 2)), np.full(8000, -1.7), rng.uniform(0, 1, 8000)])
    scan = ground.astype(np.float32)  # a flat ground 1.7 m below a LiDAR, dense enough for every voxel's normal
    T_cam_lidar = make_transform(np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]]), np.zeros(3))
    f = frame(points=scan, T_init=T_cam_lidar)
    np.testing.assert_array_equal(network_axes(f), T_cam_lidar)
    kp3d = loader_cloud(f, 2048, 0)
    data, image, pyramid = network_inputs(f, kp3d, {"seed": 0, "features": "normals", "top_rows": 50, "scale": 0.5,
                                                   "crop": (512, 160)})  # fmt: skip
    assert tuple(image.shape) == (1, 3, 160, 512)
    np.testing.assert_allclose(data["points"][0][:, 1].numpy(), 1.7, atol=1e-5)  # below the camera: +y
    feats = data["feats"].numpy()
    np.testing.assert_allclose(feats[:, 1:], np.tile([0, -1, 0], (2048, 1)), atol=1e-5)  # ground normals: up, -y
    np.testing.assert_array_equal(feats[:, 0], kp3d.reflectance)
    assert data["lengths"] == [2048, 1024, 512, 256, 128]
    np.testing.assert_array_equal(pyramid.points[0].numpy(), data["points"][0].numpy())


def test_the_nuscenes_size_feeds_intensity_at_their_scale_and_the_points_themselves():
    (row,) = default_registry().preset_rows("cofii2p-official-nuscenes")
    conf = row["confs"]["matcher"]
    assert (conf["crop"], conf["features"], conf["intensity_scale"]) == ((320, 160), "xyz", 255.0)
    assert row["confs"]["extractor2d"]["crop"] == row["confs"]["solver"]["crop"] == (320, 160)
    cloud = np.random.default_rng(4).uniform(-20, 20, (2048, 4)).astype(np.float32)
    cloud[:, 3] = np.linspace(0, 1, 2048)
    f = frame(320, 160, cloud, np.eye(4), inputs="cofii2p")  # a cofii2p-card frame: the crop, the camera-frame cloud
    kp3d = loader_cloud(f, 2048, 0)
    data, image, _ = network_inputs(f, kp3d, {**conf, "seed": 0})
    assert tuple(image.shape) == (1, 3, 160, 320)
    np.testing.assert_allclose(data["feats"][:, 0].numpy(), cloud[:, 3] * 255, rtol=1e-6)
    np.testing.assert_array_equal(data["feats"][:, 1:].numpy(), cloud[:, :3])
    with pytest.raises(ValueError, match="features 'rgb' is neither"):
        network_inputs(f, kp3d, {**conf, "seed": 0, "features": "rgb"})


def test_fine_matching_takes_the_patch_cell_of_highest_cosine_with_the_authors_axes():
    patches = torch.zeros(2, 2, 16)
    patches[0, :, 6] = torch.tensor([1.0, 0])  # point 0's best: cell 6 = row 1, column 2
    patches[1, :, 13] = torch.tensor([0.6, 0.8])  # point 1's best: cell 13 = row 3, column 1
    points = torch.tensor([[1.0, 0], [0.6, 0.8]])
    centres = torch.tensor([[20.0, 100], [8, 40]])  # (x, y) of the two patch centres
    xy, score = fine_pixels(patches, points, centres)
    # eval_all.py: x = centre x - 2 + index // 4, y = centre y - 2 + index % 4
    np.testing.assert_array_equal(xy.numpy(), [[20 - 2 + 1, 100 - 2 + 3], [8 - 2 + 2, 40 - 2 + 1]])
    np.testing.assert_allclose(score.numpy(), [1.0, 1.0], rtol=1e-6)
    upright, _ = fine_pixels(patches, points, centres, swap_patch_axes=False)
    np.testing.assert_array_equal(upright.numpy(), [[20 - 2 + 2, 100 - 2 + 1], [8 - 2 + 1, 40 - 2 + 3]])


def test_chosen_points_and_cells_map_back_to_the_extractors_rows():
    nodes = torch.tensor([[0.0, 0, 0], [1, 2, 3], [1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(node_rows(nodes, torch.tensor([[4.0, 5, 6], [1, 2, 3]])), [3, 1])
    with pytest.raises(ValueError, match="not one of the coarsest"):
        node_rows(nodes, torch.tensor([[9.0, 9, 9]]))
    # keypoint rows 0..4 fall in cells 3, -1 (outside), 1, 3, 0 -> cell 0: row 4, 1: row 2, 2: none, 3: row 0
    np.testing.assert_array_equal(cell_rows(np.array([3, -1, 1, 3, 0]), 4), [4, 2, -1, 0])


def test_the_matcher_turns_the_networks_test_outputs_into_pairs_of_extractor_rows():
    patches = torch.zeros(2, 2, 16)
    patches[0, :, 6] = torch.tensor([1.0, 0])  # point 0's best: patch row 1, column 2
    patches[1, :, 13] = torch.tensor([0.6, 0.8])  # point 1's best: patch row 3, column 1
    point_features, centres = torch.tensor([[1.0, 0], [0.6, 0.8]]), torch.tensor([[20.0, 100], [8, 40]])
    nodes = torch.tensor([[0.0, 0, 0], [1, 1, 1], [2, 2, 2]])
    chosen = nodes[[2, 0]]  # the network chose coarse points 2 and 0
    pyramid = PointPyramid([nodes], [], [], [], [np.array([70, 71, 72])])  # level rows -> the extractor's rows
    cells = np.arange(80 * 256)  # the official grid: keypoint row = cell
    conf = {**OfficialCoFiI2P.default_conf}
    matches = OfficialCoFiI2P.pairs(SimpleNamespace(conf=conf), [patches, point_features, centres, chosen], cells,
                                    pyramid)  # fmt: skip
    # centres (x, y) = (20, 8) and (100, 40); fine pixels (20 - 2 + 1, 8 - 2 + 2) = (19, 8) and (100 - 2 + 3,
    # 40 - 2 + 1) = (101, 39) (eval_all.py's axes): cells 8 * 256 + 19 and 39 * 256 + 101
    np.testing.assert_array_equal(matches.index2d, [8 * 256 + 19, 39 * 256 + 101])
    np.testing.assert_array_equal(matches.index3d, [72, 70])
    assert matches.radius_px == 4.0
    off_grid = np.where(cells == 8 * 256 + 19, -1, cells)  # no keypoint in point 0's cell: that pair is dropped
    matches = OfficialCoFiI2P.pairs(SimpleNamespace(conf=conf), [patches, point_features, centres, chosen],
                                    off_grid, pyramid)  # fmt: skip
    np.testing.assert_array_equal(matches.index3d, [70])


def test_the_solver_recovers_a_known_pose_from_exact_pairs():
    rng = np.random.default_rng(3)
    T_cam_lidar = make_transform(np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]]), np.array([0.06, -0.08, -0.27]))
    yaw = 0.7
    T_rand = make_transform(np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]),
                            np.array([3.0, -4.0, 0]))  # fmt: skip
    T_gt = T_cam_lidar @ np.linalg.inv(T_rand)
    camera = rng.uniform([-8, -1, 6], [8, 2, 40], (60, 3))  # points in front of the camera
    moved = (np.linalg.inv(T_gt) @ np.column_stack([camera, np.ones(60)]).T).T[:, :3]
    uv = (camera @ K.T)[:, :2] / camera[:, 2:]
    f = frame(points=np.column_stack([moved, np.zeros(60)]).astype(np.float32), T_init=T_cam_lidar)
    kp3d = Keypoints3D.from_index(f, np.arange(60))
    pairs = Matches(np.arange(60), np.arange(60), np.ones(60, np.float32))
    pose = OfficialPnP()(f, Keypoints2D(uv.astype(np.float32)), kp3d, pairs)
    assert pose.ok and len(pose.inliers) == 60
    np.testing.assert_allclose(pose.T, T_gt, atol=2e-3)
    assert not OfficialPnP()(
        f, Keypoints2D(uv[:3].astype(np.float32)), kp3d, Matches(*[np.arange(3)] * 2, np.ones(3, np.float32))
    ).ok
    assert OfficialPnP().conf["iterations"] == 10000 and OfficialPnP().conf["reprojection_error_px"] == 8.0


def test_the_official_size_runs_the_authors_stages():
    (row,) = default_registry().preset_rows("cofii2p-official")
    assert row["matcher"] == "cofii2p-official" and row["encoder2d"] == row["encoder3d"] == row["exchanger"] == "none"
    assert row["extractor2d"] == "cofii2p-official-grid" and row["extractor3d"] == "cofii2p-official-points"
    assert row["solver"] == "cofii2p-official-pnp"


def test_the_preset_runs_a_kitti_frame_untrained_under_the_cofii2p_card_and_says_so(shared_data, tmp_path):
    torch.set_num_threads(1)
    runs = tmp_path / "runs"
    data = ["--dataset", "kitti", "--data-root", str(shared_data / "kitti_odometry"), "--split", "all", "--frames", "1"]
    small = ["--conf", "extractor3d.max_keypoints=2048", "--threads", "1", "--protocol", "cofii2p"]  # fewer points
    assert main(["run", "--preset", "cofii2p-official", *data, *small, "--runs-dir", str(runs), "--quiet"]) == 0
    board = leaderboard.read(next((runs / "leaderboards").glob("*.csv")))
    assert len(board) == 1 and board.iloc[0]["weights"] == "untrained"
    assert board.iloc[0]["method"] == "CoFiI2P" and board.iloc[0]["Acc. (%) ↑"] == 0.0


def test_the_command_imports_authors_weights_that_the_preset_then_runs(shared_data, tmp_path):
    """under the default card: the whole image and scan, prepared by the stages."""
    reference = Path(__file__).parent / "data" / "reference" / "cofii2p"
    state, _ = recipe_state(json.loads((reference / "state_dict_shapes.json").read_text()), "preset")
    with np.load(reference / "inputs.npz") as inputs:
        state |= {k: torch.from_numpy(inputs[k]) for k in inputs.files if k.endswith("kernel_points")}
    source, weights = tmp_path / "cofii2p_kitti.t7", tmp_path / "W.pt"
    torch.save({"module." + k: v for k, v in state.items()}, source)
    assert main(["weights", "import", "cofii2p-official", str(source), "--out", str(weights)]) == 0
    torch.set_num_threads(1)
    runs = tmp_path / "runs"
    data = ["--dataset", "kitti", "--data-root", str(shared_data / "kitti_odometry"), "--split", "all", "--frames", "1"]
    small = ["--conf", "extractor3d.max_keypoints=2048", "--threads", "1", "--weights", str(weights)]
    assert main(["run", "--preset", "cofii2p-official", *data, *small, "--runs-dir", str(runs), "--quiet"]) == 0
    board = leaderboard.read(next((runs / "leaderboards").glob("*.csv")))
    assert board.iloc[0]["weights"].startswith("W@")  # the imported file, not "untrained"


def test_inference_on_the_networks_outputs_is_eval_alls_arithmetic_and_call(shared_data):
    """the reference set's frame (prepared by the authors' loader code) through our network's 'test' mode, then
    eval_all.py:99-107 written out here beside the official matcher and solver: the same pixels, points and call."""
    import cv2
    from i2pbench_cofii2p.official.importer import split
    from i2pbench_cofii2p.official.network import CoFiI2PNetwork
    from i2pbench_cofii2p.official.reference import image_tensor, pyramid

    reference = Path(__file__).parent / "data" / "reference" / "cofii2p"
    state, _ = recipe_state(json.loads((reference / "state_dict_shapes.json").read_text()), "")
    with np.load(reference / "inputs.npz") as npz:
        inputs = dict(npz)
    state |= {k: torch.from_numpy(v) for k, v in inputs.items() if k.endswith("kernel_points")}
    net = CoFiI2PNetwork().eval()
    net.load_state_dict({k.removeprefix("net."): v for k, v in split(state)[0].items()})
    data = pyramid(inputs)
    with torch.no_grad():
        out = net(data, image_tensor(inputs["image"]), None, None, None, "test")
    patches, point_features, centres, chosen = out[4:8]
    # eval_all.py: cosine similarity of each patch cell with the point's feature, argmax i, x += i // 4, y += i % 4
    similarity = torch.cosine_similarity(patches.unsqueeze(-1), point_features.unsqueeze(-1).unsqueeze(-2), dim=1)
    best = similarity.squeeze(-1).argmax(dim=1)
    theirs_xy = centres - 2
    theirs_xy[0] += best // 4
    theirs_xy[1] += best % 4
    # ours: the frame as the card gives it (the loader's moved cloud, T_init = I) with sequence 00's whole-image K
    calib = (shared_data / "kitti_odometry" / "sequences" / "00" / "calib.txt").read_text().splitlines()
    K00 = np.array([float(v) for v in calib[2].split()[1:]]).reshape(3, 4)[:, :3]
    np.testing.assert_allclose(fine_camera(K00, 1242, 375, CROP), inputs["K"], rtol=1e-6)  # their loader's K_2
    points = np.column_stack([inputs["points_0"], np.zeros(len(inputs["points_0"]))]).astype(np.float32)
    f = dataclasses.replace(frame(1242, 375, points, np.eye(4)), K=K00)
    levels = PointPyramid(data["points"], [], [], [], [np.arange(len(data["points"][-1]))])
    stage = SimpleNamespace(conf=dict(OfficialCoFiI2P.default_conf))
    matches = OfficialCoFiI2P.pairs(stage, [patches, point_features, centres, chosen], np.arange(80 * 256), levels)
    np.testing.assert_array_equal(matches.index2d, (theirs_xy[1] * 256 + theirs_xy[0]).long().numpy())
    rows = node_rows(data["points"][0], chosen).numpy()  # the chosen super-points' rows of the cloud
    kp2d, kp3d = Keypoints2D(grid_pixels(1242, 375)), Keypoints3D.from_index(f, rows)
    pairs = Matches(matches.index2d, np.arange(len(rows)), matches.score)
    # their call at OpenCV's 8 px, and at 100 px, where this untrained network's few pairs give a pose
    for threshold in (8.0, 100.0):
        cv2.setRNGSeed(0)
        ok, rvec, tvec, _ = cv2.solvePnPRansac(cameraMatrix=inputs["K"], imagePoints=theirs_xy.T.numpy(),
                                               objectPoints=chosen.numpy(), iterationsCount=10000, distCoeffs=None,
                                               reprojectionError=threshold)  # fmt: skip
        pose = OfficialPnP({"reprojection_error_px": threshold})(f, kp2d, kp3d, pairs)
        assert pose.ok == ok, threshold
    assert ok
    np.testing.assert_allclose(pose.T[:3, :3], cv2.Rodrigues(rvec)[0], atol=1e-4)
    np.testing.assert_allclose(pose.T[:3, 3], tvec.ravel(), atol=1e-3)
