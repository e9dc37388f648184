"""nuScenes through the devkit, on a dataroot built in tmp_path from the real scene-0916 records in ../shared/data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from i2pbench.data import nuscenes as nus
from i2pbench.data.nuscenes import CAMERAS, NuScenes, lidar_to_camera, read_sweep, record_matrix
from i2pbench.errors import DataError
from i2pbench.geometry import in_image, invert, project
from i2pbench.plugins import build_registry

RECORDS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "nuscenes_records"
SCENE_DIR = RECORDS / "scene-0916_sample00_b5989651"
SAMPLE = "b5989651183643369174912bc5641d3b"

pytestmark = pytest.mark.skipif(not SCENE_DIR.is_dir(), reason=f"real nuScenes records not found at {RECORDS}")


def _records() -> dict:
    return json.loads((SCENE_DIR / "calib_records.json").read_text())


def _no_dangling(record: dict) -> dict:
    # one keyframe of a 41-sample scene: prev/next would point at records we do not have
    return {**record, "prev": "", "next": ""}


def build_dataroot(root: Path, version: str, description: str | None = None) -> Path:
    """Write the thirteen devkit tables for the one real keyframe and link its files into samples/."""
    rec = _records()
    channels = ["LIDAR_TOP", *CAMERAS]
    scene = {**rec["scene"], "nbr_samples": 1, "last_sample_token": SAMPLE}
    if description is not None:
        scene["description"] = description
    log = {"token": scene["log_token"], "logfile": "n015-2018-10-08-15-36-50+0800", "vehicle": "n015",
           "date_captured": "2018-10-08", "location": "singapore-onenorth"}  # fmt: skip
    sensors = [
        {"token": rec[c]["calibrated_sensor"]["sensor_token"], "channel": c, "modality": c.split("_")[0].lower()}
        for c in channels
    ]
    tables = {
        "category": [], "attribute": [], "visibility": [], "instance": [], "sample_annotation": [],
        "sensor": sensors,
        "calibrated_sensor": [rec[c]["calibrated_sensor"] for c in channels],
        "ego_pose": [rec[c]["ego_pose"] for c in channels],
        "log": [log],
        "scene": [scene],
        "sample": [_no_dangling(rec["sample"])],
        "sample_data": [_no_dangling(rec[c]["sample_data"]) for c in channels],
        "map": [{"token": "map0", "log_tokens": [log["token"]], "category": "semantic_prior",
                 "filename": "maps/placeholder.png"}],
    }  # fmt: skip
    (root / version).mkdir(parents=True)
    for name, rows in tables.items():
        (root / version / f"{name}.json").write_text(json.dumps(rows))
    (root / "maps").mkdir()
    (root / "maps" / "placeholder.png").write_bytes(b"")  # the devkit only checks that the map file exists
    for c in channels:
        target = root / rec[c]["sample_data"]["filename"]
        target.parent.mkdir(parents=True, exist_ok=True)
        target.symlink_to(SCENE_DIR / Path(target).name)
    return root


@pytest.fixture(scope="module")
def trainval(tmp_path_factory) -> Path:
    return build_dataroot(tmp_path_factory.mktemp("nuscenes"), "v1.0-trainval")


@pytest.fixture(scope="module")
def front(trainval):
    return NuScenes("val", {"root": str(trainval)}).load(f"{SAMPLE}/CAM_FRONT")


def test_scene_0916_is_a_val_scene_so_train_and_val_hold_it(trainval):
    assert NuScenes("val", {"root": str(trainval)}).frame_ids() == [f"{SAMPLE}/CAM_FRONT"]
    assert NuScenes("train", {"root": str(trainval)}).frame_ids() == [f"{SAMPLE}/CAM_FRONT"]  # train = 700 + 150 val
    six = NuScenes("val", {"root": str(trainval), "cameras": list(CAMERAS)}).frame_ids()
    assert six == sorted(f"{SAMPLE}/{c}" for c in CAMERAS)


def test_split_sizes_follow_the_devkit():
    sizes = {s: len(NuScenes(s, {"version": v}).scene_names()) for s, (_, v) in nus.SPLITS.items()}
    assert sizes == {"train": 850, "val": 150, "test": 150, "mini_train": 8, "mini_val": 2}


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
        NuScenes("test", {"root": str(trainval)})
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
