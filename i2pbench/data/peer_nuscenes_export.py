"""Write CoFiI2P's and CorrI2P's preprocessed nuScenes layouts from a nuScenes devkit dataroot.

    cofii2p-nuscenes: {train,test}/pc/NNNNNN.npy   [4 x N] float64 x, y, z (camera frame, m), intensity (0-255)
                      {train,test}/img/NNNNNN.npy  [320 x 640 x 3] uint8 RGB: top 100 rows cut, resized x0.4
                      {train,test}/ext/NNNNNN.npy  [4 x 4] float64 P_cam_pc, LiDAR -> camera (the cloud is moved)
                      {train,test}/int/NNNNNN.npy  [3 x 3] float32 K of that image
    corri2p-nuscenes: {train,test}/PC/NNNNNN.npy   [4 x N] float32 x, y, z (camera frame, m), intensity
                      {train,test}/img/NNNNNN.npy  [160 x 320 x 3] float32 RGB values 0-255: top 100 cut, x0.2
                      {train,test}/K/NNNNNN.npy    [3 x 3] float32 K of that image

As CoFiI2P's data/build_nuscenes/build_dataset.py and CorrI2P's nuScenes_script/make_dataset.py make them
(i2pbench.data.nuscenes_sweeps for the frames and sweeps): the accumulated cloud voxelised (0.2 m CoFiI2P, 0.3 m
CorrI2P; intensity averaged, Open3D), kept only with enough points, moved into the CAM_FRONT camera frame; the frame
kept only when enough of it projects into the image. CoFiI2P names a file by the LiDAR record's place in the frame
list (gaps where one is dropped), CorrI2P numbers the kept frames from 0. `i2pbench-export.json` beside the folders
records each file's records, its sweep count and every choice the scripts leave open (docs/datasets.md).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError
from . import nuscenes_sweeps as sweeps

CAMERA = "CAM_FRONT"  # the scripts' camera_name_list
TOP_ROWS = 100  # crop_original_top_rows
MIN_POINTS = 45000  # a cloud with fewer points, before or after the voxel grid, is dropped
MIN_IN_IMAGE = 6000  # a frame with no more points projecting into the image is dropped
CHECK_POINTS = 40960  # CorrI2P counts them over a draw of input_pt_num points
METADATA = "i2pbench-export.json"
FOLDER = {"v1.0-trainval": "train", "v1.0-test": "test", "v1.0-mini": "test"}  # what the loaders read


@dataclass(frozen=True)
class Layout:
    name: str
    voxel_m: float
    image_scale: float
    folders: tuple[str, str, str, str | None]  # points, image, K, extrinsics (None: not written)
    gaps: bool  # files named by list position (gaps where dropped) or numbered from 0


LAYOUTS = {
    "cofii2p-nuscenes": Layout("cofii2p-nuscenes", 0.2, 0.4, ("pc", "img", "int", "ext"), gaps=True),
    "corri2p-nuscenes": Layout("corri2p-nuscenes", 0.3, 0.2, ("PC", "img", "K", None), gaps=False),
}


@dataclass
class NuScenesExportSummary:
    """What an export wrote and dropped, for the command's closing line and the metadata file."""

    frames: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    sweeps: list[int] = field(default_factory=list)
    bytes: int = 0
    seconds: float = 0.0
    folder: str = ""

    @property
    def total(self) -> int:
        return self.frames


def _camera_image(nusc: Any, camera: dict[str, Any], scale: float) -> tuple[np.ndarray, np.ndarray]:
    """([H x W x 3] uint8, [3 x 3] float32 K): Pillow's decode, top rows cut, resized as the scripts do."""
    import cv2
    from PIL import Image

    path = Path(nusc.dataroot) / camera["filename"]
    if not path.is_file():
        raise DataError(f"{path}: camera image not found")
    try:
        image = np.array(Image.open(path))
    except OSError as exc:
        raise DataError(f"{path}: unreadable image ({exc})") from None
    if image.ndim != 3 or image.shape[2] != 3:
        raise DataError(f"{path}: expected an RGB image, got shape {image.shape}")
    K = np.asarray(nusc.get("calibrated_sensor", camera["calibrated_sensor_token"])["camera_intrinsic"])
    K = K.astype(np.float32)
    image = image[TOP_ROWS:, :, :]
    K[1, 2] -= TOP_ROWS
    size = (int(round(image.shape[1] * scale)), int(round(image.shape[0] * scale)))
    image = cv2.resize(image, size, interpolation=cv2.INTER_LINEAR)
    K = scale * K
    K[2, 2] = 1
    return image, K


def in_image(K: np.ndarray, points: np.ndarray, image: np.ndarray) -> int:
    """How many of [3 x N] camera-frame points project into the image (its last pixel's centre included)."""
    uvz = np.dot(K, points)
    depth = uvz[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvz[:2] / uvz[2:]
    H, W = image.shape[:2]
    return int(np.sum((depth > 0) & (uv[0] >= 0) & (uv[0] <= W - 1) & (uv[1] >= 0) & (uv[1] <= H - 1)))


def _save(path: Path, array: np.ndarray) -> int:
    np.save(path, array)
    return path.stat().st_size


class _Writer:
    """One layout's files for one dataroot version."""

    def __init__(self, nusc: Any, layout: Layout, out: Path, min_points: int, min_in_image: int, skip: int) -> None:
        self.nusc, self.layout, self.min_points, self.min_in_image = nusc, layout, min_points, min_in_image
        self.skip = skip
        self.base = out / FOLDER[nusc.version]
        points = self.base / layout.folders[0]
        if points.is_dir() and any(points.iterdir()):
            raise DataError(f"{points} already holds an export (files of two exports would mix); choose another "
                            "--out or remove it")  # fmt: skip
        for name in layout.folders:
            if name is not None:
                (self.base / name).mkdir(parents=True, exist_ok=True)
        self.summary = NuScenesExportSummary(folder=FOLDER[nusc.version])
        self.files: dict[str, dict[str, Any]] = {}

    def _drop(self, reason: str) -> None:
        self.summary.dropped[reason] = self.summary.dropped.get(reason, 0) + 1

    def frame(self, position: int, lidar: dict[str, Any]) -> None:
        from ..scoring.protocol_peer import voxel_grid

        cloud = sweeps.accumulate(self.nusc, lidar, self.skip)
        if cloud.points.shape[1] < self.min_points:
            return self._drop(f"fewer than {self.min_points} points accumulated")
        rows = np.column_stack([cloud.points.T.astype(np.float64), cloud.intensity[0]])
        grid = voxel_grid(rows, self.layout.voxel_m)
        points, intensity = grid[:, :3].T.astype(np.float32), grid[:, 3][None].astype(np.float32)
        if points.shape[1] < self.min_points:
            return self._drop(f"fewer than {self.min_points} points after the {self.layout.voxel_m:g} m grid")
        cameras = sweeps.nearby_cameras(self.nusc, lidar, CAMERA)
        for token in cameras if self.layout.gaps else cameras[:1]:
            camera = self.nusc.get("sample_data", token)
            image, K = _camera_image(self.nusc, camera, self.layout.image_scale)
            P = sweeps.camera_from_lidar(self.nusc, lidar, camera)
            moved = np.dot(P[:3, :3], points) + P[:3, 3:]
            if self._inside(moved, K, image, position) > self.min_in_image:
                return self._write(position, lidar, camera, cloud.sweeps, moved, intensity, image, K, P)
        return self._drop(f"no {CAMERA} record with more than {self.min_in_image} points in its image")

    def _inside(self, moved: np.ndarray, K: np.ndarray, image: np.ndarray, position: int) -> int:
        """CoFiI2P counts every point; CorrI2P a draw of CHECK_POINTS (unseeded there; seeded here by the frame's
        place in the list, and every point when fewer)."""
        if self.layout.gaps or moved.shape[1] <= CHECK_POINTS:
            return in_image(K, moved, image)
        chosen = np.random.RandomState(position).choice(moved.shape[1], CHECK_POINTS, replace=False)
        return in_image(K, moved[:, chosen], image)

    def _write(self, position: int, lidar, camera, count: int, moved, intensity, image, K, P) -> None:
        name = f"{position if self.layout.gaps else self.summary.frames:06d}.npy"
        points_dir, image_dir, K_dir, ext_dir = self.layout.folders
        cloud = np.concatenate([moved, intensity], axis=0)
        if self.layout.gaps:
            written = _save(self.base / points_dir / name, cloud) + _save(self.base / image_dir / name, image)
            written += _save(self.base / ext_dir / name, P) + _save(self.base / K_dir / name, K)
        else:
            written = _save(self.base / points_dir / name, cloud.astype(np.float32))
            written += _save(self.base / K_dir / name, K.astype(np.float32))
            written += _save(self.base / image_dir / name, image.astype(np.float32))
        self.summary.frames += 1
        self.summary.bytes += written
        self.summary.sweeps.append(count)
        self.files[name] = {"lidar": lidar["token"], "camera": camera["token"], "sample": lidar["sample_token"],
                            "sweeps": count}  # fmt: skip


def export_nuscenes(dataroot: Path, out: Path, layout: str, version: str | None = None,
                    min_points: int = MIN_POINTS, min_in_image: int = MIN_IN_IMAGE,
                    progress: Callable[[str], None] | None = None,
                    accumulate_skip: int = sweeps.ACCUMULATE_SKIP) -> NuScenesExportSummary:  # fmt: skip
    """Export every daytime scene of the dataroot's version to `out` in `layout`'s files (`accumulate_skip`: the
    scripts' accumulation_frame_skip, 4, for 20 Hz sweeps)."""
    from .nuscenes import VERSIONS, open_devkit

    if layout not in LAYOUTS:
        raise DataError(f"unknown nuScenes layout {layout!r}; choose one of {sorted(LAYOUTS)}")
    dataroot = Path(dataroot)
    if version is None:
        present = [v for v in VERSIONS if (dataroot / v).is_dir()]
        if len(present) != 1:
            raise DataError(f"{dataroot}: holds {present or 'no v1.0-* table folder'}; name one with --version")
        version = present[0]
    if version not in FOLDER:
        raise DataError(f"--version {version!r}: choose one of {sorted(FOLDER)}")
    nusc = open_devkit(str(dataroot), version)
    writer, start, chained = (
        _Writer(nusc, LAYOUTS[layout], Path(out), min_points, min_in_image, accumulate_skip),
        time.perf_counter(),
        [],
    )
    position = 0
    for scene in sweeps.daytime_scenes(nusc):
        records, has_chain = sweeps.scene_lidar_records(nusc, scene)
        chained.append(has_chain)
        for lidar in records:
            writer.frame(position, lidar)
            position += 1
            if progress:
                progress(f"{scene['name']} {lidar['token']}")
    summary = writer.summary
    summary.seconds = time.perf_counter() - start
    _write_metadata(Path(out), writer, dataroot, version, min_points, min_in_image, all(chained))
    return summary


def _write_metadata(out: Path, writer: _Writer, dataroot: Path, version: str, min_points: int, min_in_image: int,
                    chained: bool) -> None:  # fmt: skip
    layout, summary = writer.layout, writer.summary
    path = out / METADATA
    previous = json.loads(path.read_text()) if path.is_file() else {}
    previous[summary.folder] = {
        "layout": layout.name,
        "source": str(dataroot),
        "version": version,
        "camera": CAMERA,
        "voxel_m": layout.voxel_m,
        "image_scale": layout.image_scale,
        "min_points": min_points,
        "min_in_image": min_in_image,
        "frames_from": "the 20 Hz sweep chain, every 2nd record"
        if chained
        else "every keyframe (the tables hold no sweep chain)",
        "accumulation": f"the record's sweep and up to {sweeps.ACCUMULATE} each way, every {writer.skip}th; "
        "where the chain ends or is absent, those it holds",
        "camera_choice": "the first record of the nearby list with enough points in its image"
        if layout.gaps
        else "the sample's own camera record (CorrI2P draws one of the nearby list at random, unseeded)",
        "dropped": summary.dropped,
        "files": writer.files,
    }
    path.write_text(json.dumps(previous, indent=1, sort_keys=True))
