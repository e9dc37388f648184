"""CoFiI2P's and CorrI2P's preprocessed nuScenes layouts, read as the files are (peer_nuscenes_export writes them;
docs/datasets.md describes each file).

A frame is the stored image, its K and the stored cloud, already in the camera frame (T_cam_lidar is the identity;
CoFiI2P's ext, the LiDAR -> camera matrix that moved it, is checked but not used, as its loader does not use it).
Each frame carries `draw_index`, its index in the peer loader's list: CoFiI2P's the file's place in the sorted pc/
folder, CorrI2P's the file's number. Under the layout's own card (`--protocol cofii2p` on cofii2p-nuscenes,
`corri2p` on corri2p-nuscenes) the stages get the frame that loader builds for that index
(i2pbench.scoring.protocol_peer).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..errors import DataError
from ..types import SensorFrame
from . import npy_files
from .base import Dataset
from .calibration import check_intrinsics, check_rotation
from .images import check_fits

INTENSITY_MAX = 255.0  # nuScenes' intensity scale, kept by both layouts
FOLDERS = {"train": "train", "test": "test", "val": "test"}  # the loaders read test/ for val and test


def read_cloud(path: Path) -> np.ndarray:
    """[N x 4] x, y, z (camera frame) in the file's float dtype (the loaders compute in it) and the intensity
    (0-255 in the files) scaled to [0, 1], as i2pbench's frames hold reflectance, from a [4 x N] file."""
    shape, dtype, _ = npy_files.header(path)
    if len(shape) != 2 or shape[0] != 4:
        hint = " (CorrI2P's KITTI 7 x N cloud with normals?)" if shape[:1] == (7,) else ""
        raise DataError(f"{path}: shape {shape}, expected 4 x N (x, y, z in the camera frame, intensity){hint}")
    if not np.issubdtype(dtype, np.floating):
        raise DataError(f"{path}: {dtype} values, expected floating point")
    data = npy_files.load(path)
    if not np.isfinite(data).all():
        raise DataError(f"{path}: the cloud holds NaN or inf values")
    cloud = np.array(data.T)
    cloud[:, 3] = np.clip(cloud[:, 3] / INTENSITY_MAX, 0.0, 1.0)
    return cloud


def read_image(path: Path, dtype: type) -> np.ndarray:
    """[H x W x 3] uint8 RGB from a file of `dtype` (CorrI2P stores float32 values 0-255)."""
    shape, stored, _ = npy_files.header(path)
    if len(shape) != 3 or shape[2] != 3 or stored != dtype:
        raise DataError(f"{path}: {stored} of shape {shape}, expected H x W x 3 {np.dtype(dtype)} RGB")
    image = npy_files.load(path)
    if dtype is np.uint8:
        return image
    if not np.isfinite(image).all() or image.min() < 0 or image.max() > 255:
        raise DataError(f"{path}: values outside 0-255 ({image.min():g} to {image.max():g})")
    return np.round(image).astype(np.uint8)


def read_matrix(path: Path, shape: tuple[int, int], what: str) -> np.ndarray:
    if not path.is_file():
        raise DataError(f"{path}: {what} file not found (every image needs one of the same name)")
    stored = npy_files.header(path)[0]
    if stored != shape:
        raise DataError(f"{path}: {what} has shape {stored}, expected {shape}")
    matrix = npy_files.load(path)
    if not np.issubdtype(matrix.dtype, np.floating) or not np.isfinite(matrix).all():
        raise DataError(f"{path}: {what} must hold finite floating-point values ({matrix.dtype})")
    return matrix


class _PeerNuScenes(Dataset):
    """A peer's nuScenes layout: frames `<folder>/<NNNNNN>` of train/ (split train) or test/ (val, test)."""

    splits = ("train", "val", "test")
    default_conf: ClassVar[dict[str, Any]] = {"root": None}  # folder holding train/ and test/
    match_radius_px = 3.0  # the stored images are 640 and 320 px wide, the original's 0.4 and 0.2
    folders: ClassVar[tuple[str, str, str]] = ("", "", "")  # points, image, K
    image_dtype: ClassVar[type] = np.uint8

    def __init__(self, split: str, conf: dict[str, Any] | None = None) -> None:
        super().__init__(split, conf)
        self._ids: list[str] | None = None
        self._index: dict[str, int] = {}

    @property
    def base(self) -> Path:
        path = self.root / FOLDERS[self.split]
        if not (path / self.folders[0]).is_dir():
            raise DataError(f"{path / self.folders[0]} not found (the {self.name} layout's root holds "
                            f"{FOLDERS[self.split]}/{{{','.join(self._all_folders())}}})")  # fmt: skip
        return path

    def _all_folders(self) -> list[str]:
        return list(self.folders)

    def _listed(self) -> list[str]:
        """The points folder's file names as the loader lists them, refused when the loader would fail on one."""
        folder = self.base / self.folders[0]
        names = sorted(p.name for p in folder.iterdir())
        odd = [n for n in names if not (n.endswith(".npy") and n[:-4].isdigit())]
        if odd:
            raise DataError(f"{folder}: {', '.join(odd[:3])} is not NNNNNN.npy (the loader would read it as a frame)")
        if not names:
            raise DataError(f"{folder}: no .npy files")
        return names

    def index_of(self, names: list[str]) -> list[int]:
        raise NotImplementedError

    def frame_ids(self) -> list[str]:
        if self._ids is None:
            names = self._listed()
            folder = FOLDERS[self.split]
            self._ids = [f"{folder}/{n[:-4]}" for n in names]
            self._index = dict(zip(self._ids, self.index_of(names), strict=True))
            for other in self._all_folders()[1:]:
                missing = [n for n in names if not (self.base / other / n).is_file()]
                if missing:
                    more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
                    raise DataError(f"{self.base / other}: no file for {', '.join(missing[:3])}{more} "
                                    f"(each of {self.folders[0]}/ needs one here)")  # fmt: skip
        return list(self._ids)

    def draw_index(self, frame_id: str) -> int:
        if frame_id not in self._index:
            self.frame_ids()
        if frame_id not in self._index:
            raise DataError(f"dataset {self.name!r}: frame {frame_id!r} is not in split {self.split!r}")
        return self._index[frame_id]

    def _paths(self, frame_id: str) -> list[Path]:
        folder, sep, stem = frame_id.partition("/")
        if not sep or folder != FOLDERS[self.split] or not stem.isdigit():
            raise DataError(f"dataset {self.name!r}: frame id {frame_id!r} is not '{FOLDERS[self.split]}/NNNNNN'")
        return [self.root / folder / name / f"{stem}.npy" for name in self._all_folders()]

    def check_extra(self, paths: list[Path]) -> None:
        """Layout files the loader reads besides points, image and K."""

    def load(self, frame_id: str) -> SensorFrame:
        paths = self._paths(frame_id)
        points_path, image_path, K_path = paths[:3]
        if not image_path.is_file():
            raise DataError(f"{image_path}: image file not found (every {self.folders[0]}/ file needs one)")
        image = read_image(image_path, self.image_dtype)
        K = read_matrix(K_path, (3, 3), "K")
        check_intrinsics(K.astype(np.float64), str(K_path))
        check_fits(image_path, image, K, K_path)
        self.check_extra(paths)
        points = read_cloud(points_path)
        return SensorFrame(
            dataset=self.name,
            frame_id=frame_id,
            image=image,
            points=points,
            ring=np.zeros(len(points), np.int16),
            K=K.astype(np.float64),
            T_cam_lidar=np.eye(4),
            match_radius_px=self.match_radius_px,
            source=str(points_path),
            draw_index=self.draw_index(frame_id),
            preprocessed=True,
        )

    def sequence_of(self, frame_id: str) -> str:
        return FOLDERS[self.split]

    def frame_files(self, frame_id: str) -> list[Path]:
        return self._paths(frame_id)


class CoFiI2PNuScenes(_PeerNuScenes):
    """CoFiI2P's layout, {train,test}/{pc,img,int,ext}/NNNNNN.npy; the loader's index is the place in sorted pc/."""

    name = "cofii2p-nuscenes"
    folders = ("pc", "img", "int")

    def _all_folders(self) -> list[str]:
        return [*self.folders, "ext"]

    def index_of(self, names: list[str]) -> list[int]:
        return list(range(len(names)))

    def check_extra(self, paths: list[Path]) -> None:
        ext = read_matrix(paths[3], (4, 4), "ext (LiDAR -> camera)")
        check_rotation(ext[:3, :3].astype(np.float64), str(paths[3]), "the rotation of ext")


class CorrI2PNuScenes(_PeerNuScenes):
    """CorrI2P's layout, {train,test}/{PC,img,K}/NNNNNN.npy numbered from 0 (the loader opens '%06d.npy' % index)."""

    name = "corri2p-nuscenes"
    folders = ("PC", "img", "K")
    image_dtype = np.float32

    def index_of(self, names: list[str]) -> list[int]:
        numbers = [int(n[:-4]) for n in names]
        if numbers != list(range(len(numbers))):
            gap = next(i for i, n in enumerate(numbers) if n != i)
            raise DataError(f"{self.base / self.folders[0]}: files must be numbered 000000 up without gaps, as the "
                            f"loader opens index i as '%06d.npy' % i (found {names[gap]} where {gap:06d}.npy "
                            "belongs)")  # fmt: skip
        return numbers
