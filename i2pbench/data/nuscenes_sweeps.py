"""The nuScenes steps CorrI2P's and CoFiI2P's build scripts share, as they compute them: which LiDAR records become
frames, the sweeps accumulated round each, the camera records near it, and their poses.

Read from CoFiI2P's data/build_nuscenes/{build_datainfo,build_dataset}.py (CorrI2P's nuScenes_script/ holds the
same functions): every daytime scene's LIDAR_TOP records from its first keyframe, every `frame_skip`-th of the
20 Hz chain; round each, `ACCUMULATE` sweeps each way, every `ACCUMULATE_SKIP`-th, taken into its LiDAR frame through
the ego poses; each return inside the ego car's box (|x| < 0.8 m, |y| < 2.7 m, LiDAR frame) dropped; every pose and
calibration a 4 x 4 float64 matrix of float32-rounded pyquaternion rotation and translation. Where a dataroot's
tables hold no sweep chain (a dataroot built from keyframe records), the keyframes are followed instead
(docs/datasets.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError

FRAME_SKIP = 2  # build_datainfo.py main(): every second LiDAR record of the 20 Hz chain
ACCUMULATE = 3  # Options_Nuscenes.accumulation_frame_num: sweeps each way
ACCUMULATE_SKIP = 4  # accumulation_frame_skip: the 4th, 8th, 12th sweep each way
MAX_CAMERA_M = 10.0  # build_datainfo.py main(): max_translation of a nearby camera record
EGO_BOX_M = (0.8, 2.7)  # |x|, |y| of the ego car's box, LiDAR frame
# scene tokens the build scripts drop as night scenes besides those whose description says so (v1.0-test's)
NIGHT_SCENES = frozenset(
    {
        "e59a4d0cc6a84ed59f78fb21a45cdcb4",
        "7209495d06f24712a063ac6c4a9b403b",
        "3d776ea805f240bb925bd9b50b258416",
        "48f81c548d0148fc8010a73d70b2ef9c",
        "2ab683f384234dce89800049dec19a30",
        "7edca4c44eac4f52a3105e1794e56b7e",
        "81c939ce8c0d4cc7b159cb5ed4c4e712",
        "24e6e64ecf794be4a51f7454c8b6d0b2",
        "828ed34a5e0c456fbf0751cabbab3341",
        "edfd6cfd1805477fbeadbd29f39ed599",
        "7692a3e112b44b408d191e45954a813c",
        "58d27a9f83294d99a4ff451dcad5f4d2",
        "a1573aef0bf74324b373dd8a22b4dd68",
        "ba06095d4e2e425b8e398668abc301d8",
        "7c315a1db2ac49439d281605f3cca6be",
        "732d7a84353f4ada803a9a115728496c",
        "1630a1d9cf8a46b3843662a23126e3f6",
        "f437809584344859882bdff7f8784c43",
    }
)


@dataclass
class Accumulated:
    """[3 x N] points (LiDAR frame of the frame's record) and [1 x N] float32 intensity, and how many records."""

    points: np.ndarray
    intensity: np.ndarray
    sweeps: int


def pose_matrix(record: dict[str, Any]) -> np.ndarray:
    """[4 x 4] float64 of an ego_pose or calibrated_sensor record, its values rounded to float32 as the scripts do."""
    from pyquaternion import Quaternion

    T = np.identity(4)
    T[:3, :3] = np.asarray(Quaternion(record["rotation"]).rotation_matrix).astype(np.float32)
    T[:3, 3] = np.asarray(record["translation"]).astype(np.float32)
    return T


def record_pose(nusc: Any, record: dict[str, Any]) -> np.ndarray:
    return pose_matrix(nusc.get("ego_pose", record["ego_pose_token"]))


def record_calibration(nusc: Any, record: dict[str, Any]) -> np.ndarray:
    return pose_matrix(nusc.get("calibrated_sensor", record["calibrated_sensor_token"]))


def camera_from_lidar(nusc: Any, lidar: dict[str, Any], camera: dict[str, Any]) -> np.ndarray:
    """P_cam_pc: LiDAR (at its time) -> camera (at its), multiplied in the scripts' order."""
    inv = np.linalg.inv
    lidar_side = np.dot(record_pose(nusc, lidar), record_calibration(nusc, lidar))
    return np.dot(inv(record_calibration(nusc, camera)), np.dot(inv(record_pose(nusc, camera)), lidar_side))


def read_lidar(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """([3 x N] float32 x, y, z; [1 x N] float32 intensity) of a .pcd.bin, the ego car's box removed."""
    if not path.is_file():
        raise DataError(f"{path}: LiDAR file not found")
    size = path.stat().st_size
    if size % 20 or size == 0:
        raise DataError(f"{path}: {size} bytes is not a positive multiple of 20 (float32 x, y, z, intensity, ring)")
    raw = np.fromfile(path, dtype=np.float32).reshape(-1, 5)[:, :4].T
    if not np.isfinite(raw).all():
        raise DataError(f"{path}: the sweep holds NaN or inf values")
    inside = (np.abs(raw[0]) < EGO_BOX_M[0]) & (np.abs(raw[1]) < EGO_BOX_M[1])
    kept = raw[:, ~inside]
    return kept[:3], kept[3:4]


def _lidar(nusc: Any, token: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    record = nusc.get("sample_data", token)
    points, intensity = read_lidar(Path(nusc.dataroot) / record["filename"])
    return points, intensity, record_pose(nusc, record)


def accumulate(nusc: Any, lidar: dict[str, Any], skip: int = ACCUMULATE_SKIP) -> Accumulated:
    """The record's own sweep, then up to ACCUMULATE later and ACCUMULATE earlier ones, every `skip`-th (those the
    chain holds)."""
    points, intensity, pose = _lidar(nusc, lidar["token"])
    clouds, intensities = [points], [intensity]
    world_to_this = np.linalg.inv(pose)
    vehicle_from_lidar = record_calibration(nusc, lidar)
    lidar_from_vehicle = np.linalg.inv(vehicle_from_lidar)
    for direction in ("next", "prev"):
        record, counter, taken = lidar, 1, 0
        while taken < ACCUMULATE and record[direction] != "":
            if counter % skip == 0:
                other, other_intensity, other_pose = _lidar(nusc, record[direction])
                moved = np.dot(np.dot(lidar_from_vehicle, np.dot(world_to_this, other_pose)), vehicle_from_lidar)
                homogeneous = np.concatenate([other, np.ones((1, other.shape[1]), dtype=other.dtype)], axis=0)
                clouds.append(np.dot(moved, homogeneous)[:3])
                intensities.append(other_intensity)
                taken += 1
            counter += 1
            record = nusc.get("sample_data", record[direction])
    return Accumulated(np.concatenate(clouds, axis=1), np.concatenate(intensities, axis=1), len(clouds))


def daytime_scenes(nusc: Any) -> list[dict[str, Any]]:
    return [s for s in nusc.scene if not ("night" in s["description"] or "Night" in s["description"]
                                          or s["token"] in NIGHT_SCENES)]  # fmt: skip


def scene_lidar_records(nusc: Any, scene: dict[str, Any]) -> tuple[list[dict[str, Any]], bool]:
    """(the scene's LiDAR records the scripts make frames of, whether the tables chain its sweeps). Without a
    sweep chain, every keyframe (frame_skip counts 20 Hz sweeps, not the 2 Hz keyframes)."""
    sample = nusc.get("sample", scene["first_sample_token"])
    record = nusc.get("sample_data", sample["data"]["LIDAR_TOP"])
    if record["next"] == "" and sample["next"] != "":
        records = [record]
        while sample["next"] != "":
            sample = nusc.get("sample", sample["next"])
            records.append(nusc.get("sample_data", sample["data"]["LIDAR_TOP"]))
        return records, False
    records, counter = [record], 1
    while record["next"] != "":
        record = nusc.get("sample_data", record["next"])
        counter += 1
        if counter % FRAME_SKIP == 0:
            records.append(record)
    return records, True


def nearby_cameras(nusc: Any, lidar: dict[str, Any], channel: str = "CAM_FRONT") -> list[str]:
    """The camera records the scripts pair a LiDAR record with: its sample's, then later ones, then earlier ones,
    each within MAX_CAMERA_M of the LiDAR's ego pose. As published, the search starts one record out, so the two
    records next to the sample's are never listed."""
    lidar_inv = np.linalg.inv(record_pose(nusc, lidar))
    data = nusc.get("sample", lidar["sample_token"])["data"]
    if channel not in data:
        raise DataError(f"{Path(nusc.dataroot) / nusc.version / 'sample.json'}: sample {lidar['sample_token']} has "
                        f"no {channel} record (it has {', '.join(sorted(data))})")  # fmt: skip
    first = nusc.get("sample_data", data[channel])
    tokens = [first["token"]]
    for direction in ("next", "prev"):
        if first[direction] == "":
            continue
        camera = nusc.get("sample_data", first[direction])
        while camera[direction] != "":
            token = camera[direction]
            camera = nusc.get("sample_data", token)
            if np.linalg.norm(np.dot(lidar_inv, record_pose(nusc, camera))[:3, 3]) >= MAX_CAMERA_M:
                break
            tokens.append(token)
    return tokens
