"""Writes synthetic frames as a nuScenes dataroot that the official devkit loads: `v1.0-mini/*.json` tables,
`samples/LIDAR_TOP/*.pcd.bin` (float32 x, y, z, intensity 0-255, ring) and `samples/CAM_FRONT/*.jpg`.

The rig copies nuScenes': a 32-beam LiDAR 1.84 m up, turned -90 deg about z (x right, y forward), sweeping clockwise
from behind-left with points stored firing by firing (ring 0 = bottom beam), and CAM_FRONT at 1600x900. Scenes take
the v1.0-mini scene names, alternating the devkit's mini_train and mini_val lists, so both mini splits get scenes.
Each sample is an independent street; the LiDAR and camera share a timestamp and ego pose (the scene is static).
"""

from __future__ import annotations

import hashlib
import json
from functools import cache
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from . import pinned
from .camera import render
from .lidar import scan
from .raycast import Caster
from .rig import Camera, Lidar, on_uneven_road
from .scene import build_scene
from .version import GENERATOR_VERSION, SCENE_DRAWS

MINI_TRAIN = [
    "scene-0061",
    "scene-0553",
    "scene-0655",
    "scene-0757",
    "scene-0796",
    "scene-1077",
    "scene-1094",
    "scene-1100",
]
MINI_VAL = ["scene-0103", "scene-0916"]
LIDAR_RECORD = {"translation": [0.943713, 0.0, 1.84023], "rotation": [np.sqrt(0.5), 0.0, 0.0, -np.sqrt(0.5)]}
CAMERA_RECORD = {
    "translation": [1.70079118954, 0.0159456324149, 1.51095763913],
    "rotation": [0.5, -0.5, 0.5, -0.5],  # camera z forward = ego x, camera x right = ego -y, camera y down = ego -z
    "camera_intrinsic": [
        [1266.417203046554, 0.0, 816.2670197447984],
        [0.0, 1266.417203046554, 491.50706579294757],
        [0.0, 0.0, 1.0],
    ],
}
IMAGE_SIZE = (1600, 900)
T0 = 1533151603547590  # first timestamp (microseconds)


def _token(*parts) -> str:
    return hashlib.md5("/".join(str(p) for p in parts).encode()).hexdigest()


def _matrix(record: dict) -> np.ndarray:
    """4x4 pose from a record's translation and w, x, y, z quaternion, as the devkit reads it."""
    w, x, y, z = record["rotation"]
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
    T[:3, 3] = record["translation"]
    return T


@cache
def rig() -> tuple[Lidar, Camera]:
    """HDL-32E (ring 0 = -30.67 deg) and CAM_FRONT, posed in the ego frame (= the scene's world frame)."""
    lidar = Lidar(
        elevations_deg=np.linspace(-30.67, 10.67, 32),
        pose=_matrix(LIDAR_RECORD),
        steps=1080,
        azimuth0=np.pi,
        clockwise=True,
        max_range=70.0,
    )
    T_ego_cam = _matrix(CAMERA_RECORD)
    camera = Camera(
        K=np.array(CAMERA_RECORD["camera_intrinsic"]),
        T_cam_lidar=np.linalg.inv(T_ego_cam) @ lidar.pose,
        size=IMAGE_SIZE,
    )
    return lidar, camera


def simulate(seed: int, scene: int, sample: int) -> tuple[np.ndarray, np.ndarray]:
    """([N x 5] float32 sweep in nuScenes' .pcd.bin layout, [900 x 1600 x 3] uint8 RGB) of one sample, made in this
    process (`generate_nuscenes` runs it in pinned workers)."""
    rng = np.random.default_rng([SCENE_DRAWS, int(seed), 1_000_000 + scene, sample])
    caster = Caster(build_scene(rng))
    lidar, camera = rig()
    lidar = on_uneven_road(lidar, rng)
    points, ring, step = scan(caster, lidar, rng)
    order = np.lexsort((ring, step))  # firing by firing: every beam of one azimuth step, bottom beam first
    intensity = np.round(255 * points[order, 3].astype(np.float64) ** 2)
    sweep = np.column_stack([points[order, :3], intensity, ring[order]]).astype(np.float32)
    return sweep, render(caster, camera, lidar.pose, rng)


def generate_nuscenes(
    dataroot: Path, n_scenes: int = 2, samples_per_scene: int = 2, seed: int = 0, version: str = "v1.0-mini"
) -> Path:
    """Write a dataroot with n_scenes scenes of samples_per_scene keyframes each; returns dataroot."""
    dataroot = Path(dataroot)
    tables = _static_tables(dataroot, seed)
    names = [n for pair in zip(MINI_TRAIN, MINI_VAL + [None] * 6, strict=True) for n in pair if n]
    calls = [(seed, i, k) for i in range(n_scenes) for k in range(samples_per_scene)]
    made = dict(zip([call[1:] for call in calls], pinned.run(simulate, calls), strict=True))
    for i in range(n_scenes):
        name = names[i] if i < len(names) else f"scene-synthetic-{i:04d}"
        _write_scene(dataroot, tables, seed, i, name, [made[i, k] for k in range(samples_per_scene)])
    (dataroot / version).mkdir(parents=True, exist_ok=True)
    for name, records in tables.items():
        (dataroot / version / f"{name}.json").write_text(json.dumps(records, indent=1))
    return dataroot


def _static_tables(dataroot: Path, seed: int) -> dict[str, list[dict]]:
    """Sensors, calibrations, one log and its map; the annotation tables stay empty."""
    lidar_sensor, cam_sensor = _token(seed, "sensor", "LIDAR_TOP"), _token(seed, "sensor", "CAM_FRONT")
    log, map_token = _token(seed, "log"), _token(seed, "map")
    map_file = f"maps/{map_token}.png"
    (dataroot / "maps").mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(dataroot / map_file), np.zeros((4, 4), np.uint8))  # the devkit only checks the mask exists
    return {
        "category": [],
        "attribute": [],
        "visibility": [],
        "instance": [],
        "sample_annotation": [],
        "sensor": [
            {"token": lidar_sensor, "channel": "LIDAR_TOP", "modality": "lidar"},
            {"token": cam_sensor, "channel": "CAM_FRONT", "modality": "camera"},
        ],
        "calibrated_sensor": [
            {
                "token": _token(seed, "calib", "LIDAR_TOP"),
                "sensor_token": lidar_sensor,
                "camera_intrinsic": [],
                **{k: LIDAR_RECORD[k] for k in ("translation", "rotation")},
            },
            {"token": _token(seed, "calib", "CAM_FRONT"), "sensor_token": cam_sensor, **CAMERA_RECORD},
        ],
        "log": [
            {
                "token": log,
                "logfile": f"synthetic-v{GENERATOR_VERSION}-seed{seed}",
                "vehicle": "synthetic",
                "date_captured": "2018-08-01",
                "location": "synthetic-streets",
            }
        ],
        "map": [{"token": map_token, "log_tokens": [log], "category": "semantic_prior", "filename": map_file}],
        "scene": [],
        "sample": [],
        "sample_data": [],
        "ego_pose": [],
    }


def _write_scene(dataroot: Path, tables: dict, seed: int, scene: int, name: str, frames: list[tuple]) -> None:
    """One scene's tables and files; `frames` holds each sample's (sweep, image)."""
    n_samples = len(frames)
    samples = [_token(seed, "sample", scene, k) for k in range(n_samples)]
    tables["scene"].append(
        {
            "token": _token(seed, "scene", scene),
            "log_token": tables["log"][0]["token"],
            "nbr_samples": n_samples,
            "first_sample_token": samples[0],
            "last_sample_token": samples[-1],
            "name": name,
            "description": f"synthetic street, seed {seed}",
        }
    )
    for k, token in enumerate(samples):
        stamp = T0 + scene * 20_000_000 + k * 500_000
        tables["sample"].append(
            {
                "token": token,
                "timestamp": stamp,
                "scene_token": tables["scene"][-1]["token"],
                "prev": samples[k - 1] if k else "",
                "next": samples[k + 1] if k + 1 < n_samples else "",
            }
        )
        sweep, image = frames[k]
        pose = {"rotation": [1.0, 0.0, 0.0, 0.0], "translation": [600.0 + 10.0 * k, 1600.0 + 100.0 * scene, 0.0]}
        for channel, ext in (("LIDAR_TOP", "pcd.bin"), ("CAM_FRONT", "jpg")):
            filename = f"samples/{channel}/synthetic__{channel}__{stamp}.{ext}"
            (dataroot / filename).parent.mkdir(parents=True, exist_ok=True)
            if channel == "LIDAR_TOP":
                sweep.astype("<f4").tofile(dataroot / filename)
            else:
                cv2.imwrite(str(dataroot / filename), image[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, 92])
            _sample_data(tables, seed, scene, k, n_samples, token, channel, filename, stamp, pose)


def _sample_data(tables, seed, scene, k, n_samples, sample, channel, filename, stamp, pose) -> None:
    """A keyframe sample_data record with its ego pose (same token, as in nuScenes) and prev/next links."""
    token = _token(seed, "sd", channel, scene, k)
    width, height = IMAGE_SIZE if channel == "CAM_FRONT" else (0, 0)
    tables["ego_pose"].append({"token": token, "timestamp": stamp, **pose})
    tables["sample_data"].append(
        {
            "token": token,
            "sample_token": sample,
            "ego_pose_token": token,
            "calibrated_sensor_token": _token(seed, "calib", channel),
            "timestamp": stamp,
            "fileformat": filename.rsplit(".", 1)[-1] if channel == "CAM_FRONT" else "pcd",
            "is_key_frame": True,
            "height": height,
            "width": width,
            "filename": filename,
            "prev": _token(seed, "sd", channel, scene, k - 1) if k else "",
            "next": _token(seed, "sd", channel, scene, k + 1) if k + 1 < n_samples else "",
        }
    )
