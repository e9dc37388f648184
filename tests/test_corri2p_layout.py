"""CorrI2P's preprocessed KITTI layout: the export from the original layout, the `corri2p-kitti` reader, its errors,
and the peer cards' frame built on it as the peers' loaders build it (tests/test_corri2p_layout_peers.py runs the
loaders themselves)."""

from __future__ import annotations

import random
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import SAMPLE_DATA, sample

from i2pbench.boards import leaderboard
from i2pbench.cli import main
from i2pbench.data.corri2p_export import read_scan
from i2pbench.data.corri2p_kitti import Corri2PKitti
from i2pbench.data.images import read_image
from i2pbench.data.kitti import KittiOdometry
from i2pbench.errors import DataError
from i2pbench.scoring.cards import COFII2P, CORRI2P
from i2pbench.scoring.protocol import Protocol
from i2pbench.scoring.protocol_peer import draw_pose, seed_of

KITTI = SAMPLE_DATA / "kitti_odometry"


@pytest.fixture(scope="module")
def export(tmp_path_factory) -> Path:
    """The six real frames (sequences 00 and 01) exported by the command."""
    sample("kitti_odometry")
    out = tmp_path_factory.mktemp("corri2p") / "export"
    assert main(["data", "export", "--layout", "corri2p", "--from", str(KITTI), "--out", str(out), "--quiet"]) == 0
    return out


@pytest.fixture
def layout(export, tmp_path) -> Path:
    """A copy of the export to break."""
    shutil.copytree(export, tmp_path / "root")
    return tmp_path / "root"


def _load(root: Path):
    return Corri2PKitti("all", {"root": str(root)}).load("01/000000")


def test_export_writes_the_scripts_arrays(export):
    seq = export / "sequences" / "01"
    cloud = np.load(seq / "pc_npy_with_normal" / "000000.npy")
    assert cloud.dtype == np.float32 and cloud.shape[0] == 7
    scan = read_scan(KITTI / "sequences" / "01" / "velodyne" / "000000.bin")
    assert 0.2 * len(scan) < cloud.shape[1] < len(scan)  # a 0.1 m grid merges returns
    normals = cloud[4:]
    assert np.allclose(np.linalg.norm(normals, axis=0), 1.0, atol=1e-5)
    assert (normals[2] >= 0).all()  # oriented to +z
    # reflectance of the raw return nearest each voxel point, checked by brute force on a few points
    for j in (0, cloud.shape[1] // 2, cloud.shape[1] - 1):
        nearest = np.argmin(((scan[:, :3].astype(np.float64) - cloud[:3, j]) ** 2).sum(axis=1))
        assert cloud[3, j] == scan[nearest, 3]
    # each voxel point is the mean of raw returns: it lies within the 0.1 m box of its own voxel's returns
    assert np.abs(cloud[:3].min(axis=1) - scan[:, :3].min(axis=0)).max() < 0.1
    K = np.load(seq / "K_P2" / "000000.npy")
    assert K.dtype == np.float32 and K[0, 0] == np.float32(707.0493) and K[1, 2] == np.float32(180.5066)
    image = np.load(seq / "img_P2" / "000000.npy")
    assert image.dtype == np.uint8
    assert np.array_equal(image, read_image(KITTI / "sequences" / "01" / "image_2" / "000000.png"))
    calib = KITTI / "sequences" / "01" / "calib.txt"
    assert (export / "calib" / "01" / "calib.txt").read_bytes() == calib.read_bytes()


def test_reader_hands_the_files_as_they_are(export):
    sensor = _load(export)
    cloud = np.load(export / "sequences" / "01" / "pc_npy_with_normal" / "000000.npy")
    assert np.array_equal(sensor.points, cloud[:4].T)
    assert sensor.image.shape == (370, 1224, 3) and sensor.K[0, 2] == np.float32(604.0814)
    # T_cam_lidar = P2's baseline @ Tr: baseline t_x = (45.75831 - 604.0814 * 0.004981016) / 707.0493
    baseline = (45.75831 - 604.0814 * 0.004981016) / 707.0493
    assert sensor.T_cam_lidar[0, 3] == pytest.approx(-0.02236670891814 + baseline, abs=1e-6)
    assert sensor.draw_index == 10  # after sequence 00's five frames, two entries (P2, P3) a frame


def test_camera_3_is_the_odd_index(layout):
    for seq in (layout / "sequences").iterdir():
        shutil.copytree(seq / "img_P2", seq / "img_P3")
        shutil.copytree(seq / "K_P2", seq / "K_P3")
    three = Corri2PKitti("all", {"root": str(layout), "camera": 3}).load("01/000000")
    assert three.draw_index == 11
    # P3's baseline: t_x = (-334.1081 - 604.0814 * 0.003201153) / 707.0493, 0.536 m from camera 2's
    two = _load(layout)
    gap = (45.75831 - 604.0814 * 0.004981016 + 334.1081 + 604.0814 * 0.003201153) / 707.0493
    assert two.T_cam_lidar[0, 3] - three.T_cam_lidar[0, 3] == pytest.approx(gap, abs=1e-6)


def test_seeds_are_cofii2ps():
    (state,) = np.random.SeedSequence([7]).generate_state(1)
    assert seed_of(7) == int(state)
    assert seed_of(7, seed=3) != seed_of(7)
    rand = random.Random(seed_of(7))
    tx, ty, tz, rx, ry, rz = (rand.uniform(-a, a) for a in (10, 0, 10, 0, 2 * np.pi, 0))
    P = draw_pose(random.Random(seed_of(7)), 10.0, 2 * np.pi)
    assert P[0, 3] == np.float32(tx) and P[2, 3] == np.float32(tz) and P[1, 3] == 0
    assert P[0, 0] == np.float32(np.cos(ry)) and P[0, 2] == np.float32(np.sin(ry)) and P[1, 1] == 1


@pytest.mark.parametrize("card, count", [(CORRI2P, 40960), (COFII2P, 20480)])
def test_peer_card_frame(export, card, count):
    sensor = _load(export)
    frame = card.protocol(0, "corri2p-kitti").apply(sensor)
    assert frame.image.shape == (160, 512, 3) and frame.points.shape == (count, 4)
    # K x0.5, then the centre crop of the 612 x 185 image at (int(100 / 2), int(25 / 2)) = (50, 12)
    assert frame.K[0, 0] == pytest.approx(707.0493 * 0.5, abs=1e-4)
    assert frame.K[0, 2] == pytest.approx(604.0814 * 0.5 - 50, abs=1e-4)
    assert frame.K[1, 2] == pytest.approx(180.5066 * 0.5 - 12, abs=1e-4)
    # the ground truth takes the moved cloud back into the camera frame, where the pose rotates about y only
    T = frame.T_gt
    assert abs(T[1, 1] - 1) < 1e-6 and abs(T[1, 3]) < 1e-6
    assert frame.T_init is not None and np.array_equal(frame.T_init, np.eye(4))
    cam = frame.points[:, :3].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    lidar_in_cam = sensor.points[:, :3].astype(np.float64) @ sensor.T_cam_lidar[:3, :3].T + sensor.T_cam_lidar[:3, 3]
    assert np.abs(cam.min(axis=0) - lidar_in_cam.min(axis=0)).max() < 0.1  # same scene, voxel means within a voxel
    again = card.protocol(0, "corri2p-kitti").apply(sensor)
    assert np.array_equal(again.points, frame.points)  # the draw is the index's, run after run


def test_default_card_gives_the_files(export):
    sensor = _load(export)
    frame = Protocol().apply(sensor)
    assert frame.image.shape == sensor.image.shape and len(frame.points) == len(sensor.points)


def test_missing_K_file(layout):
    (layout / "sequences" / "01" / "K_P2" / "000000.npy").unlink()
    with pytest.raises(DataError, match=r"K_P2/000000\.npy"):
        Corri2PKitti("all", {"root": str(layout)}).frame_ids()


def test_four_rows_where_seven_are_expected(layout):
    path = layout / "sequences" / "01" / "pc_npy_with_normal" / "000000.npy"
    np.save(path, np.load(path)[:4])
    with pytest.raises(DataError, match=r"000000\.npy: shape \(4, \d+\), expected 7 x N.*raw scan"):
        _load(layout)


def test_truncated_npy(layout):
    path = layout / "sequences" / "01" / "pc_npy_with_normal" / "000000.npy"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match=rf"000000\.npy: truncated \.npy: {len(data) // 2} of the {len(data)} bytes"):
        _load(layout)


def test_K_of_another_sequence(layout):
    K = np.load(layout / "sequences" / "01" / "K_P2" / "000000.npy")
    K[0, 2] = 607.1928  # sequence 03's principal point
    np.save(layout / "sequences" / "01" / "K_P2" / "000000.npy", K)
    with pytest.raises(DataError, match="not the one .*calib.txt gives its sequence.*image and K of different frames"):
        _load(layout)


def test_image_of_another_size(layout):
    seq = layout / "sequences" / "01"
    shutil.copy(seq / "img_P2" / "000000.npy", seq / "img_P2" / "000001.npy")
    shutil.copy(seq / "K_P2" / "000000.npy", seq / "K_P2" / "000001.npy")
    shutil.copy(seq / "pc_npy_with_normal" / "000000.npy", seq / "pc_npy_with_normal" / "000001.npy")
    np.save(seq / "img_P2" / "000001.npy", np.load(seq / "img_P2" / "000000.npy")[:360, :1200])
    with pytest.raises(DataError, match=r"000001\.npy: a 1200 x 360 image where this sequence's are 1224 x 370"):
        Corri2PKitti("all", {"root": str(layout)}).load("01/000001")


@pytest.mark.parametrize("card", ["corri2p", "cofii2p"])
def test_the_export_and_the_original_layout_give_the_same_board(export, tmp_path, card):
    """The must-show of issue 41, on two frames: the same frames reach the stages from either layout."""
    boards = []
    for dataset, root in (("corri2p-kitti", export), ("kitti", KITTI)):
        runs = tmp_path / dataset
        assert main(["run", "--preset", "classic-oracle", "--dataset", dataset, "--data-root", str(root), "--split",
                     "all", "--frames", "2", "--protocol", card, "--runs-dir", str(runs), "--quiet"]) == 0  # fmt: skip
        board = leaderboard.read(next((runs / "leaderboards").glob("*.csv")))
        boards.append(board.drop(columns=[c for c in board.columns if "latency" in c or c == "dataset"]))
    assert boards[0].iloc[0][leaderboard.ACC] == 100.0  # the oracle registers both frames
    pd.testing.assert_frame_equal(boards[0], boards[1])


def test_the_raw_layout_gives_the_exports_frames(export):
    """Under a loader card, a kitti frame is the export's frame: the same grid and draws (points within float32
    rounding of a ~1e-8 m calibration difference, docs/datasets.md)."""
    protocol = CORRI2P.protocol(0, "kitti")
    raw = KittiOdometry("all", {"root": str(KITTI)})
    exported = Corri2PKitti("all", {"root": str(export)})
    for frame_id in ("00/000003", "01/000000"):
        a, b = protocol.apply(raw.load(frame_id)), protocol.apply(exported.load(frame_id))
        assert np.array_equal(a.image, b.image) and np.array_equal(a.K, b.K)
        assert a.points.shape == b.points.shape == (40960, 4)
        assert np.abs(a.points - b.points).max() < 1e-4
        assert np.abs(a.T_gt - b.T_gt).max() < 1e-9
