"""CoFiI2P's and CorrI2P's preprocessed nuScenes layouts: the export from a devkit dataroot of the real scene-0916
keyframes, the readers, their errors, the frame the layout's card builds, and an oracle run on the export
(tests/test_nuscenes_layout_peers.py runs the authors' loaders themselves)."""

from __future__ import annotations

import json
import random
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import SAMPLE_DATA, sample

from i2pbench.boards import leaderboard
from i2pbench.cli import main
from i2pbench.data.nuscenes import NuScenes, read_sweep
from i2pbench.data.nuscenes_dataroot import build_dataroot
from i2pbench.data.peer_nuscenes import CoFiI2PNuScenes, CorrI2PNuScenes
from i2pbench.errors import DataError, I2PBenchError
from i2pbench.geometry.transforms import invert
from i2pbench.scoring import installed
from i2pbench.scoring.cards import COFII2P, CORRI2P
from i2pbench.scoring.protocol_peer import draw_pose

RECORDS = SAMPLE_DATA / "nuscenes_real"
FIRST_SAMPLE = "b5989651183643369174912bc5641d3b"  # scene-0916_sample00, the first keyframe in time
LAYOUT_FILES = {"cofii2p-nuscenes": ("pc", "img", "int", "ext"), "corri2p-nuscenes": ("PC", "img", "K")}


@pytest.fixture(scope="module")
def dataroot(tmp_path_factory) -> Path:
    sample("nuscenes_real")
    root = tmp_path_factory.mktemp("nuscenes") / "dataroot"
    build_dataroot([RECORDS], root, "v1.0-test")
    return root


@pytest.fixture(scope="module")
def exports(dataroot) -> dict[str, Path]:
    """Both layouts exported by the command, the scripts' thresholds off (one sweep a frame: no sweeps here)."""
    out = {}
    for layout in LAYOUT_FILES:
        out[layout] = dataroot.parent / layout
        assert main(["data", "export", "--layout", layout, "--from", str(dataroot), "--out", str(out[layout]),
                     "--min-points", "0", "--min-in-image", "0", "--quiet"]) == 0  # fmt: skip
    return out


def _copy(exports, layout: str, tmp_path: Path) -> Path:
    shutil.copytree(exports[layout], tmp_path / layout)
    return tmp_path / layout


def test_files_are_named_typed_and_shaped_as_the_scripts_make_them(exports):
    names = [f"{i:06d}.npy" for i in range(10)]
    for layout, folders in LAYOUT_FILES.items():
        for folder in folders:
            assert sorted(p.name for p in (exports[layout] / "test" / folder).iterdir()) == names
    cofi, corr = exports["cofii2p-nuscenes"] / "test", exports["corri2p-nuscenes"] / "test"
    pc, img = np.load(cofi / "pc" / names[0]), np.load(cofi / "img" / names[0])
    assert pc.dtype == np.float64 and pc.shape[0] == 4 and img.dtype == np.uint8 and img.shape == (320, 640, 3)
    assert np.load(cofi / "ext" / names[0]).dtype == np.float64 and np.load(cofi / "int" / names[0]).dtype == np.float32
    PC, image = np.load(corr / "PC" / names[0]), np.load(corr / "img" / names[0])
    assert PC.dtype == np.float32 and PC.shape[0] == 4 and image.dtype == np.float32 and image.shape == (160, 320, 3)
    assert np.array_equal(image, np.round(image)) and image.max() <= 255  # a uint8 image stored as float32
    assert PC.shape[1] < pc.shape[1]  # CorrI2P's 0.3 m grid against CoFiI2P's 0.2 m


def test_K_and_ext_are_the_devkits_cut_and_scaled(exports, dataroot):
    """K: the camera_intrinsic with 100 rows cut then x0.4 (x0.2); ext: the time-aware LiDAR -> camera matrix
    i2pbench's nuScenes reader computes, up to the scripts' float32 rounding of each record."""
    records = json.loads((RECORDS / "scene-0916_sample00_b5989651" / "calib_records.json").read_text())
    K = np.array(records["CAM_FRONT"]["calibrated_sensor"]["camera_intrinsic"])
    for layout, folder, scale in (("cofii2p-nuscenes", "int", 0.4), ("corri2p-nuscenes", "K", 0.2)):
        stored = np.load(exports[layout] / "test" / folder / "000000.npy")
        expected = np.array([[K[0, 0] * scale, 0, K[0, 2] * scale], [0, K[1, 1] * scale, (K[1, 2] - 100) * scale],
                             [0, 0, 1]])  # fmt: skip
        assert np.abs(stored - expected).max() < 1e-3
    _, T = NuScenes("test", {"root": str(dataroot), "version": "v1.0-test"}).calibration(f"{FIRST_SAMPLE}/CAM_FRONT")
    ext = np.load(exports["cofii2p-nuscenes"] / "test" / "ext" / "000000.npy")
    # the ego poses' global translations (~1 km here) rounded to float32 move t by up to an ulp there, 6e-5 m
    assert np.abs(ext[:3, :3] - T[:3, :3]).max() < 1e-6 and np.abs(ext[:3, 3] - T[:3, 3]).max() < 1e-4


def test_cloud_is_the_sweep_gridded_without_the_ego_box_moved_into_the_camera(exports, dataroot):
    cofi = exports["cofii2p-nuscenes"] / "test"
    ext, pc = np.load(cofi / "ext" / "000000.npy"), np.load(cofi / "pc" / "000000.npy")
    lidar = (invert(ext) @ np.vstack([pc[:3], np.ones(pc.shape[1])]))[:3]
    # voxel means of returns outside |x| < 0.8, |y| < 2.7 lie at most a 0.2 m voxel inside that box
    assert not ((np.abs(lidar[0]) < 0.6) & (np.abs(lidar[1]) < 2.5)).any()
    meta = json.loads((exports["cofii2p-nuscenes"] / "i2pbench-export.json").read_text())["test"]
    sweep = next(dataroot.glob("samples/LIDAR_TOP/*1538984233547259.pcd.bin"))
    raw = np.fromfile(sweep, np.float32).reshape(-1, 5)
    assert 0.2 * len(raw) < pc.shape[1] < len(raw)
    assert pc[3].max() <= raw[:, 3].max() and pc[3].min() >= raw[:, 3].min()  # averaged raw intensity, 0-255
    assert meta["files"]["000000.npy"]["sweeps"] == 1 and meta["files"]["000000.npy"]["sample"] == FIRST_SAMPLE
    assert meta["frames_from"] == "every keyframe (the tables hold no sweep chain)"
    assert read_sweep(sweep, 0.0)[0].shape[0] == len(raw)


def test_the_scripts_thresholds_drop_every_single_sweep_frame_and_say_so(dataroot, tmp_path, capsys):
    assert main(["data", "export", "--layout", "cofii2p-nuscenes", "--from", str(dataroot), "--out",
                 str(tmp_path / "x"), "--quiet"]) == 0  # fmt: skip
    err = capsys.readouterr().err
    assert "0 frame(s)" in err and "10 dropped: fewer than 45000 points accumulated" in err
    assert "--min-points, --min-in-image" in err
    assert main(["data", "export", "--layout", "corri2p-nuscenes", "--from", str(dataroot), "--out",
                 str(tmp_path / "y"), "--quiet", "--min-points", "0"]) == 0  # fmt: skip
    assert "10 dropped: no CAM_FRONT record with more than 6000 points in its image" in capsys.readouterr().err


@pytest.mark.parametrize("cls", [CoFiI2PNuScenes, CorrI2PNuScenes])
def test_reader_hands_the_stored_frame(exports, cls):
    dataset = cls("test", {"root": str(exports[cls.name])})
    ids = dataset.frame_ids()
    assert ids == [f"test/{i:06d}" for i in range(10)] and dataset.draw_index("test/000007") == 7
    frame = dataset.load("test/000003")
    stored = np.load(exports[cls.name] / "test" / cls.folders[0] / "000003.npy")
    assert np.array_equal(frame.points[:, :3], stored[:3].T) and np.allclose(frame.points[:, 3], stored[3] / 255)
    assert np.array_equal(frame.T_cam_lidar, np.eye(4)) and frame.image.dtype == np.uint8
    assert np.array_equal(frame.image, np.load(exports[cls.name] / "test" / "img" / "000003.npy").astype(np.uint8))


@pytest.mark.parametrize(("cls", "card", "count", "scale"), [(CoFiI2PNuScenes, COFII2P, 20480, 0.5),
                                                              (CorrI2PNuScenes, CORRI2P, 40960, 1.0)])  # fmt: skip
def test_the_layouts_card_builds_its_loaders_frame(exports, cls, card, count, scale):
    """Seeded with the index as CoFiI2P's loader seeds: the legacy numpy draw of `count` points, P_random from
    Python's random, moved in the camera frame; image resized by `scale` and centre-cropped to 160 x 320."""
    dataset = cls("test", {"root": str(exports[cls.name])})
    sensor = dataset.load("test/000004")
    frame = card.protocol(0, dataset.name).apply(sensor)
    stored = np.load(exports[cls.name] / "test" / cls.folders[0] / "000004.npy")
    n = stored.shape[1]
    chosen = np.random.RandomState(4).choice(n, n, replace=False)  # fewer than `count`: all, repeated, then a draw
    repeats = count // n
    indices = np.concatenate([np.tile(np.arange(n), repeats), chosen[: count - repeats * n]])
    P = draw_pose(random.Random(4), 10.0, 2 * np.pi)
    expected = (P[:3, :3] @ stored[:3, indices].astype(np.float64) + P[:3, 3:]).T
    assert frame.points.shape == (count, 4) and np.abs(frame.points[:, :3] - expected).max() < 1e-4
    assert np.allclose(frame.T_gt, np.linalg.inv(P)) and frame.image.shape == (160, 320, 3)
    K = np.load(exports[cls.name] / "test" / cls.folders[2] / "000004.npy")
    assert np.allclose(frame.K[:2], K[:2] * scale)  # the crop's offset is 0 for both stored sizes


def test_the_other_papers_card_is_refused_naming_the_layouts():
    with pytest.raises(I2PBenchError, match="cofii2p-nuscenes holds the files cofii2p's loader reads"):
        installed.for_run("corri2p", 0, "cofii2p-nuscenes")
    assert installed.for_run("cofii2p", 0, "cofii2p-nuscenes").points == 20480


@pytest.mark.parametrize("layout", list(LAYOUT_FILES))
def test_an_oracle_run_on_the_export_registers_every_frame(exports, tmp_path, layout):
    card = layout.split("-")[0]
    assert main(["run", "--preset", "classic-oracle", "--dataset", layout, "--data-root", str(exports[layout]),
                 "--split", "test", "--protocol", card, "--runs-dir", str(tmp_path), "--quiet"]) == 0  # fmt: skip
    board = leaderboard.read(next((tmp_path / "leaderboards").glob("*.csv")))
    assert board.iloc[0]["frames"] == 10 and board.iloc[0][leaderboard.ACC] == 100.0


def test_missing_K_file(exports, tmp_path):
    root = _copy(exports, "corri2p-nuscenes", tmp_path)
    (root / "test" / "K" / "000002.npy").unlink()
    with pytest.raises(DataError, match=r"test/K: no file for 000002\.npy"):
        CorrI2PNuScenes("test", {"root": str(root)}).frame_ids()


def test_wrong_cloud_shape(exports, tmp_path):
    root = _copy(exports, "cofii2p-nuscenes", tmp_path)
    np.save(root / "test" / "pc" / "000001.npy", np.zeros((7, 100)))
    with pytest.raises(DataError, match=r"000001\.npy: shape \(7, 100\), expected 4 x N .*7 x N cloud with normals"):
        CoFiI2PNuScenes("test", {"root": str(root)}).load("test/000001")


def test_truncated_npy(exports, tmp_path):
    root = _copy(exports, "cofii2p-nuscenes", tmp_path)
    path = root / "test" / "pc" / "000005.npy"
    path.write_bytes(path.read_bytes()[:5000])
    with pytest.raises(DataError, match=r"000005\.npy: truncated \.npy: 5000 of the \d+ bytes"):
        CoFiI2PNuScenes("test", {"root": str(root)}).load("test/000005")


def test_wrong_ext_and_image_dtype(exports, tmp_path):
    root = _copy(exports, "cofii2p-nuscenes", tmp_path)
    np.save(root / "test" / "ext" / "000000.npy", np.eye(3))
    with pytest.raises(DataError, match=r"ext \(LiDAR -> camera\) has shape \(3, 3\), expected \(4, 4\)"):
        CoFiI2PNuScenes("test", {"root": str(root)}).load("test/000000")
    corr = _copy(exports, "corri2p-nuscenes", tmp_path)
    image = np.load(corr / "test" / "img" / "000000.npy")
    np.save(corr / "test" / "img" / "000000.npy", image.astype(np.uint8))
    with pytest.raises(DataError, match=r"uint8 of shape \(160, 320, 3\), expected H x W x 3 float32 RGB"):
        CorrI2PNuScenes("test", {"root": str(corr)}).load("test/000000")


def test_corri2p_numbering_gap(exports, tmp_path):
    root = _copy(exports, "corri2p-nuscenes", tmp_path)
    for folder in LAYOUT_FILES["corri2p-nuscenes"]:
        (root / "test" / folder / "000003.npy").unlink()
    with pytest.raises(DataError, match=r"found 000004\.npy where 000003\.npy belongs"):
        CorrI2PNuScenes("test", {"root": str(root)}).frame_ids()


def test_image_of_another_layout(exports, tmp_path):
    """A CoFiI2P image (640 x 320) beside a K for 320 x 160 puts the principal point outside the middle half."""
    root = _copy(exports, "cofii2p-nuscenes", tmp_path)
    K = np.load(root / "test" / "int" / "000000.npy")
    np.save(root / "test" / "int" / "000000.npy", (K * 0.5).astype(np.float32) + np.diag([0, 0, 0.5]).astype("f4"))
    with pytest.raises(DataError, match="does not fit this calibration"):
        CoFiI2PNuScenes("test", {"root": str(root)}).load("test/000000")


def test_a_flag_of_the_other_source_is_refused(tmp_path, capsys):
    out = str(tmp_path / "o")
    assert main(["data", "export", "--layout", "corri2p", "--from", str(tmp_path), "--out", out,
                 "--min-points", "3"]) == 2  # fmt: skip
    assert "--layout corri2p: --min-points belongs to the other source" in capsys.readouterr().err
    assert main(["data", "export", "--layout", "cofii2p-nuscenes", "--from", str(tmp_path), "--out", out,
                 "--sequences", "00"]) == 2  # fmt: skip
    assert "--layout cofii2p-nuscenes: --sequences belongs to the other source" in capsys.readouterr().err
    assert main(["data", "export", "--layout", "cofii2p-nuscenes", "--from", str(tmp_path), "--out", out]) == 2
    assert f"{tmp_path}: holds no v1.0-* table folder; name one with --version" in capsys.readouterr().err


def test_an_export_over_another_is_refused(exports, dataroot, capsys):
    """CoFiI2P names files by list position: a second export's files would mix with the first's."""
    out = str(exports["cofii2p-nuscenes"])
    assert main(["data", "export", "--layout", "cofii2p-nuscenes", "--from", str(dataroot), "--out", out]) == 2
    assert "test/pc already holds an export (files of two exports would mix)" in capsys.readouterr().err
