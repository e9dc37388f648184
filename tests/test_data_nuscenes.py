"""nuScenes through the devkit, on a dataroot built in tmp_path from the real scene-0916 records in ../shared/data."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import SAMPLE_DATA, needs_nuscenes

from i2pbench.data import nuscenes as nus
from i2pbench.data.nuscenes import CAMERAS, NuScenes, lidar_to_camera, read_sweep, record_matrix
from i2pbench.data.nuscenes_dataroot import build_dataroot as build
from i2pbench.errors import DataError
from i2pbench.geometry.transforms import in_image, invert, project
from i2pbench.registry.build import build_registry
from i2pbench.runs.store import ResultsStore

RECORDS = SAMPLE_DATA / "nuscenes_records"
SCENE_DIR = RECORDS / "scene-0916_sample00_b5989651"
SAMPLE = "b5989651183643369174912bc5641d3b"

pytestmark = needs_nuscenes(SCENE_DIR.name)


def _records() -> dict:
    return json.loads((SCENE_DIR / "calib_records.json").read_text())


def build_dataroot(root: Path, version: str, description: str | None = None) -> Path:
    """The one real keyframe as a devkit dataroot (the library's builder); `description` rewrites its scene's."""
    build([RECORDS], root, version)
    if description is not None:
        scenes = json.loads((root / version / "scene.json").read_text())
        (root / version / "scene.json").write_text(json.dumps([{**s, "description": description} for s in scenes]))
    return root


@pytest.fixture(scope="module")
def trainval(tmp_path_factory) -> Path:
    return build_dataroot(tmp_path_factory.mktemp("nuscenes"), "v1.0-trainval")


@pytest.fixture(scope="module")
def front(trainval):
    return NuScenes("val", {"root": str(trainval)}).load(f"{SAMPLE}/CAM_FRONT")


def test_scene_0916_is_a_val_scene_so_trainval_and_val_hold_it_and_train_does_not(trainval):
    assert NuScenes("val", {"root": str(trainval)}).frame_ids() == [f"{SAMPLE}/CAM_FRONT"]
    assert NuScenes("trainval", {"root": str(trainval)}).frame_ids() == [f"{SAMPLE}/CAM_FRONT"]  # 700 + 150 val
    with pytest.raises(DataError, match="no frames for split 'train'"):
        NuScenes("train", {"root": str(trainval)}).frame_ids()
    six = NuScenes("val", {"root": str(trainval), "cameras": list(CAMERAS)}).frame_ids()
    assert six == sorted(f"{SAMPLE}/{c}" for c in CAMERAS)


def test_split_sizes_follow_the_devkit():
    sizes = {s: len(NuScenes(s, {"version": v}).scene_names()) for s, (_, v) in nus.SPLITS.items()}
    assert sizes == {"trainval": 850, "train": 700, "val": 150, "test": 150, "mini_train": 8, "mini_val": 2}


def test_mini_version_and_its_splits(tmp_path):
    root = build_dataroot(tmp_path, "v1.0-mini")
    assert NuScenes("mini_val", {"root": str(root), "version": "v1.0-mini"}).frame_ids() == [f"{SAMPLE}/CAM_FRONT"]
    with pytest.raises(DataError, match="no frames for split 'mini_train'"):
        NuScenes("mini_train", {"root": str(root), "version": "v1.0-mini"}).frame_ids()


def test_frame_contents(front):
    assert front.dataset == "nuscenes" and front.match_radius_px == 5.0 and front.frame_id == f"{SAMPLE}/CAM_FRONT"
    assert front.image.shape == (900, 1600, 3) and front.image.dtype == np.uint8
    assert front.points.dtype == np.float32 and front.points.shape[1] == 4
    assert 0.0 <= front.points[:, 3].min() and front.points[:, 3].max() <= 1.0
    assert front.source.endswith("LIDAR_TOP__1538984233547259.pcd.bin")
    assert np.allclose(front.K, _records()["CAM_FRONT"]["K"])


def test_ego_returns_removed_and_ring_kept(front):
    raw = np.fromfile(front.source, np.float32).reshape(-1, 5)
    assert len(raw) == 34560
    # measured: 6775 of 34560 returns (19.6%) lie within 1.2 m of the sensor, all on the car's roof or at the origin
    assert len(front.points) == 34560 - 6775
    assert np.hypot(front.points[:, 0], front.points[:, 1]).min() >= 1.2
    assert front.ring.dtype == np.int16 and front.ring.min() == 0 and front.ring.max() == 31
    kept = np.hypot(raw[:, 0], raw[:, 1]) >= 1.2
    assert np.array_equal(front.ring, raw[kept, 4].astype(np.int16))
    assert np.allclose(front.points[:, 3] * 255.0, raw[kept, 3], atol=1e-4)


def test_projection_lands_many_points_in_cam_front(front):
    uv, in_front = project(front.K, front.T_cam_lidar, front.points[:, :3])
    inside = in_image(uv, in_front, front.image_size)
    assert 3_400 <= inside.sum() <= 4_000  # measured 3691 of 27785 (CAM_BACK, wider lens: 5039)


@pytest.mark.parametrize("camera", CAMERAS)
def test_chain_matches_the_time_aware_lidar2cam_of_the_records(trainval, camera):
    K, T = NuScenes("val", {"root": str(trainval), "cameras": [camera]}).calibration(f"{SAMPLE}/{camera}")
    expected = np.array(_records()[camera]["lidar2cam"])
    assert np.allclose(T, expected, atol=1e-6)
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)


def test_chain_equals_a_hand_composition_and_differs_from_the_static_one():
    rec = _records()
    lid, cam = rec["LIDAR_TOP"], rec["CAM_FRONT"]
    T = lidar_to_camera(lid["calibrated_sensor"], lid["ego_pose"], cam["calibrated_sensor"], cam["ego_pose"])
    # a point 10 m ahead of the LiDAR, mapped step by step to the global frame and back into the camera
    X = np.array([0.0, 10.0, 0.0, 1.0])
    world = record_matrix(lid["ego_pose"]) @ record_matrix(lid["calibrated_sensor"]) @ X
    in_cam = np.linalg.solve(record_matrix(cam["ego_pose"]) @ record_matrix(cam["calibrated_sensor"]), world)
    assert np.allclose(T @ X, in_cam)
    static = invert(record_matrix(cam["calibrated_sensor"])) @ record_matrix(lid["calibrated_sensor"])
    # the car moved 14 cm between the LiDAR and CAM_FRONT timestamps (35 ms)
    assert np.linalg.norm(T[:3, 3] - static[:3, 3]) == pytest.approx(0.14, abs=0.02)


def test_record_matrix_reads_w_first_quaternions():
    T = record_matrix({"rotation": [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)], "translation": [1.0, 2.0, 3.0]})
    assert np.allclose(T[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]]) and np.allclose(T[:3, 3], [1, 2, 3])


def test_night_scenes_can_be_excluded(tmp_path):
    root = build_dataroot(tmp_path, "v1.0-trainval", description="Night, parking lot, peds")
    assert len(NuScenes("val", {"root": str(root)}).frame_ids()) == 1
    with pytest.raises(DataError, match="no frames"):
        NuScenes("val", {"root": str(root), "exclude_night": True}).frame_ids()


def test_missing_version_folder_names_the_path(tmp_path):
    with pytest.raises(DataError, match=f"{tmp_path / 'v1.0-trainval'} not found"):
        NuScenes("val", {"root": str(tmp_path)}).frame_ids()


def test_bad_conf_and_frame_ids(trainval):
    with pytest.raises(DataError, match="needs version 'v1.0-test'"):
        NuScenes("test", {"root": str(trainval), "version": "v1.0-trainval"})
    with pytest.raises(DataError, match="unknown cameras"):
        NuScenes("val", {"cameras": ["CAM_TOP"]})
    with pytest.raises(DataError, match="no frame 'nope/CAM_FRONT'"):
        NuScenes("val", {"root": str(trainval)}).load("nope/CAM_FRONT")


def test_truncated_or_nan_sweep_names_the_file(tmp_path):
    sweep = tmp_path / "sweep.pcd.bin"
    raw = np.fromfile(next(SCENE_DIR.glob("*LIDAR_TOP*")), np.float32)
    raw[:-3].tofile(sweep)
    with pytest.raises(DataError, match=f"{sweep}.*multiple of 20"):
        read_sweep(sweep, 1.2)
    raw[7] = np.nan
    raw.tofile(sweep)
    with pytest.raises(DataError, match=f"{sweep}: 1 points hold NaN"):
        read_sweep(sweep, 1.2)


def test_missing_devkit_says_how_to_install(monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "nuscenes.nuscenes", None)
    with pytest.raises(DataError, match="pip install --no-deps nuscenes-devkit"):
        NuScenes("val").scene_names()


def test_registered_through_the_entry_point(monkeypatch):
    monkeypatch.setenv("I2PBENCH_LOAD_PLUGINS", "datasets")
    assert build_registry().dataset("nuscenes") is NuScenes


# ---- the version follows the split; a dataroot built from record folders by `i2pbench data nuscenes-dataroot` ----

REAL = RECORDS.parent / "nuscenes_real"
FIRST, SECOND, LAST = SAMPLE, "ac8b4d49731d43289579f014cb7c97ef", "b4ff30109dd14c89b24789dc5713cf8c"


def test_version_follows_the_split_and_cache_identity_is_unchanged(trainval, tmp_path):
    val = NuScenes("val", {"root": str(trainval)})
    assert val.conf["version"] == "v1.0-trainval" and val.identity()["version"] == "v1.0-trainval"
    mini = build_dataroot(tmp_path, "v1.0-mini")
    assert NuScenes("mini_val", {"root": str(mini)}).frame_ids() == [f"{SAMPLE}/CAM_FRONT"]


def test_default_test_split_uses_the_only_version_on_disk_and_says_so(trainval, capsys):
    dataset = NuScenes("test", {"root": str(trainval)})
    assert (dataset.split, dataset.conf["version"]) == ("val", "v1.0-trainval")
    assert f"{trainval} holds v1.0-trainval only (no v1.0-test): using split 'val' instead of 'test'" in (
        capsys.readouterr().err
    )
    assert dataset.frame_ids() == [f"{SAMPLE}/CAM_FRONT"]


def test_with_two_versions_on_disk_the_test_split_is_not_guessed(tmp_path):
    build_dataroot(tmp_path, "v1.0-trainval")
    build([RECORDS], tmp_path, "v1.0-mini")  # same files, second table folder
    dataset = NuScenes("test", {"root": str(tmp_path)})
    assert (dataset.split, dataset.conf["version"]) == ("test", "v1.0-test")
    with pytest.raises(DataError, match="v1.0-test not found"):
        dataset.frame_ids()


@pytest.fixture(scope="module")
def real_root(tmp_path_factory) -> Path:
    if not REAL.is_dir():
        pytest.skip(f"{REAL} not found")
    from i2pbench.cli import main

    root = tmp_path_factory.mktemp("dataroot") / "nuscenes"
    # sample00 is in both sources: given twice, it counts once
    assert main(["data", "nuscenes-dataroot", "--records", str(RECORDS), *map(str, sorted(REAL.iterdir())),
                 "--out", str(root)]) == 0  # fmt: skip
    return root


def _table(root: Path, name: str) -> list[dict]:
    return json.loads((root / "v1.0-trainval" / f"{name}.json").read_text())


def test_dataroot_command_writes_the_tables_of_all_record_folders(real_root):
    sizes = {n: len(_table(real_root, n)) for n in ("sample", "scene", "sample_data", "calibrated_sensor", "sensor")}
    # 10 keyframes x 7 channels; one rig, so 7 calibrated sensors shared by every keyframe
    assert sizes == {"sample": 10, "scene": 1, "sample_data": 70, "calibrated_sensor": 7, "sensor": 7}
    samples = _table(real_root, "sample")
    assert [s["token"] for s in samples[:2]] == [FIRST, SECOND] and samples[0]["prev"] == ""
    assert samples[0]["next"] == SECOND and samples[1]["prev"] == FIRST and samples[-1]["next"] == ""
    (scene,) = _table(real_root, "scene")
    assert (scene["nbr_samples"], scene["first_sample_token"], scene["last_sample_token"]) == (10, FIRST, LAST)
    front = real_root / next(d["filename"] for d in _table(real_root, "sample_data") if "CAM_FRONT__" in d["filename"])
    assert front.is_symlink() and front.resolve() == (SCENE_DIR / front.name).resolve()  # linked, first source wins
    assert len(NuScenes("val", {"root": str(real_root), "cameras": list(CAMERAS)}).frame_ids()) == 60


def test_dataroot_command_refuses_an_existing_version_folder(real_root, capsys):
    from i2pbench.cli import main

    assert main(["data", "nuscenes-dataroot", "--records", str(RECORDS), "--out", str(real_root)]) == 2
    assert f"{real_root / 'v1.0-trainval'} already exists" in capsys.readouterr().err


def test_run_with_the_default_split_works_on_a_built_dataroot(real_root, tmp_path):
    cmd = [sys.executable, "-m", "i2pbench.cli", "run", "--matcher", "oracle", "--dataset", "nuscenes",
           "--data-root", str(real_root), "--frames", "2", "--runs-dir", str(tmp_path / "runs"),
           "--out", str(tmp_path / "board"), "--threads", "1", "--quiet"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert "using split 'val' instead of 'test'" in done.stderr
    records = ResultsStore(tmp_path / "runs" / "nuscenes-val").load()
    assert len(records) == 2 and (records["status"] == "ok").all()
    assert (records["rte_m"] < 0.2).all() and (records["rre_deg"] < 1.0).all()  # oracle matches: near exact
