"""CorrI2P's preprocessed KITTI (what CoFiI2P and ICL read unchanged), read as the files are.

Layout (docs/datasets.md; `i2pbench data export --layout corri2p` writes it): `calib/NN/calib.txt`,
`sequences/NN/{img_P2, K_P2, img_P3, K_P3, pc_npy_with_normal}/NNNNNN.npy`. A frame is the full-size image, its K,
the 0.1 m voxel cloud with reflectance (LiDAR frame; the normals are not passed on, no stage reads them) and
T_cam_lidar = P's baseline @ Tr, computed from the calibration's float32 values as the loaders' KittiCalibHelper does.

Each frame also carries `draw_index`, its index in the list the peers' loaders build over the split's sequences
(frame i of a sequence is 2 i, camera 3's 2 i + 1, after the earlier sequences' frames): under a peer card
(`--protocol corri2p`, `cofii2p`) the stages get exactly the frame those loaders build for that index
(i2pbench.scoring.protocol_peer), CoFiI2P's `SeedSequence([index])` draw included. The ring is unknown after
voxelisation (zeros). A frame's `dataset` is "kitti", the recording, so that its other draws are those of the same
frame read by `kitti`: under those cards the two datasets give the same board.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..errors import DataError
from ..types import SensorFrame
from . import npy_files
from .base import Dataset
from .calibration import check_intrinsics, check_rotation
from .images import check_fits
from .kitti import BENCHMARK_SEQUENCES, SPLIT_SEQUENCES, _parse_calib

# the frames' `dataset`, which keys every per-frame draw (the protocol's T_rand, the extractors' keypoint subsets):
# these are KITTI Odometry's recordings, so a frame draws as the same frame read by `kitti` does
RECORDING = "kitti"
POINT_ROWS = 7  # x, y, z, reflectance, normal x, y, z
K_AGREES = 1e-3  # px: a K file is the calibration's P's 3 x 3 (stored as float32, ~1e-4 px off at most)


@lru_cache(maxsize=64)
def _peer_calib(path: str, mtime_ns: int, camera: int) -> tuple[np.ndarray, np.ndarray]:
    """(K [3 x 3] float64, T_cam_lidar [4 x 4] float64) as KittiCalibHelper makes them: values rounded to float32,
    P's baseline (tx, ty, tz) solved in float32, the product in float64."""
    calib = _parse_calib(Path(path), (f"P{camera}", "Tr"))
    mats = {}
    for key in (f"P{camera}", "Tr"):
        if key not in calib or calib[key].size != 12:
            raise DataError(f"{path}: no {key} line of 12 numbers (needed for camera {camera})")
        mats[key] = calib[key].reshape(3, 4).astype(np.float32)
    P, tr = mats[f"P{camera}"], mats["Tr"]
    check_intrinsics(P[:, :3].astype(np.float64), f"{path}: P{camera}")
    check_rotation(tr[:, :3].astype(np.float64), path, "the rotation of Tr")
    fx, fy, cx, cy, tz = P[0, 0], P[1, 1], P[0, 2], P[1, 2], P[2, 3]
    baseline = np.eye(4)
    baseline[:3, 3] = [(P[0, 3] - cx * tz) / fx, (P[1, 3] - cy * tz) / fy, tz]
    T = np.eye(4)
    T[:3, :] = tr
    return P[:, :3].astype(np.float64), baseline @ T


def peer_calib(calib: Path, camera: int) -> tuple[np.ndarray, np.ndarray]:
    if not calib.is_file():
        raise DataError(f"{calib}: calibration file not found (this layout keeps it in calib/NN/calib.txt)")
    K, T = _peer_calib(str(calib), calib.stat().st_mtime_ns, camera)
    return K.copy(), T.copy()


def read_points(path: Path) -> np.ndarray:
    """[N x 4] float32 x, y, z, reflectance from a [7 x N] pc_npy_with_normal file."""
    shape, dtype, _ = npy_files.header(path)
    if len(shape) != 2 or shape[0] != POINT_ROWS:
        hint = " (a raw scan's x, y, z, reflectance without normals?)" if shape[:1] == (4,) else ""
        raise DataError(f"{path}: shape {shape}, expected {POINT_ROWS} x N (x, y, z, reflectance, normal x, y, z)"
                        f"{hint}")  # fmt: skip
    data = npy_files.load(path)
    if not np.issubdtype(dtype, np.floating) or not np.isfinite(data).all():
        raise DataError(f"{path}: expected finite floating-point values ({dtype})")
    return np.ascontiguousarray(data[:4].T, dtype=np.float32)


def read_image(path: Path) -> np.ndarray:
    shape, dtype, _ = npy_files.header(path)
    if len(shape) != 3 or shape[2] != 3 or dtype != np.uint8:
        raise DataError(f"{path}: {dtype} of shape {shape}, expected H x W x 3 uint8 RGB")
    return npy_files.load(path)


def read_K(path: Path, calib_K: np.ndarray, calib: Path) -> np.ndarray:
    if not path.is_file():
        raise DataError(f"{path}: K file not found (every img_PN/NNNNNN.npy needs K_PN/NNNNNN.npy)")
    K = npy_files.load(path)
    if K.shape != (3, 3):
        raise DataError(f"{path}: K has shape {K.shape}, expected (3, 3)")
    check_intrinsics(K.astype(np.float64), str(path))
    if np.abs(K - calib_K).max() > K_AGREES:
        raise DataError(f"{path}: this K ({K[0, 0]:.2f}, {K[0, 2]:.2f}, {K[1, 2]:.2f}) is not the one {calib} gives "
                        f"its sequence ({calib_K[0, 0]:.2f}, {calib_K[0, 2]:.2f}, {calib_K[1, 2]:.2f}): image and K "
                        "of different frames?")  # fmt: skip
    return K.astype(np.float64)


class Corri2PKitti(Dataset):
    """CorrI2P's KITTI layout by sequence, split as `kitti`: trainval 00-08, train 00-07, val 08, test 09-10, all."""

    name = "corri2p-kitti"
    splits = ("train", "val", "trainval", "test", "all")
    default_conf: ClassVar[dict[str, Any]] = {
        "root": None,  # folder holding calib/ and sequences/; None reads I2PBENCH_CORRI2P_KITTI_ROOT
        "camera": 2,  # 2 (img_P2, K_P2) or 3 (img_P3, K_P3)
        "sequences": None,  # explicit list of sequences, overriding the split; each must exist
    }
    match_radius_px = 3.0

    def __init__(self, split: str, conf: dict[str, Any] | None = None) -> None:
        super().__init__(split, conf)
        if self.conf["camera"] not in (2, 3):
            raise DataError(f"dataset {self.name!r}: camera must be 2 or 3, got {self.conf['camera']!r}")
        self._ids: list[str] | None = None
        self._index: dict[str, int] = {}

    @property
    def sequences_dir(self) -> Path:
        path = self.root / "sequences"
        if not path.is_dir():
            raise DataError(f"{path} not found (the CorrI2P layout's root holds calib/ and sequences/NN/...)")
        return path

    def sequences(self) -> list[str]:
        base = self.sequences_dir
        if self.conf["sequences"] is not None:
            names = sorted({f"{int(s):02d}" if str(s).isdigit() else str(s) for s in self.conf["sequences"]})
            absent = [str(base / n) for n in names if not (base / n).is_dir()]
            if absent:
                raise DataError(f"dataset {self.name!r}: requested sequences not found: {', '.join(absent)}")
            return names
        on_disk = sorted(p.name for p in base.iterdir() if p.is_dir())
        if self.split == "all":
            return on_disk
        extra = [s for s in on_disk if s not in BENCHMARK_SEQUENCES] if self.split == "val" else []
        return [s for s in SPLIT_SEQUENCES[self.split] if (base / s).is_dir()] + extra

    def _dirs(self, sequence: str) -> tuple[Path, Path, Path]:
        seq, c = self.sequences_dir / sequence, self.conf["camera"]
        return seq / f"img_P{c}", seq / f"K_P{c}", seq / "pc_npy_with_normal"

    def _stems(self, sequence: str) -> list[str]:
        """Frame stems of a sequence, after checking each image has its K and its cloud."""
        images, Ks, clouds = self._dirs(sequence)
        stems = sorted(p.stem for p in images.glob("*.npy"))
        if not stems:
            raise DataError(f"{images}: no .npy images")
        for folder, what in ((Ks, "K"), (clouds, "cloud")):
            missing = [s for s in stems if not (folder / f"{s}.npy").is_file()]
            if missing:
                more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
                names = ", ".join(str(folder / f"{s}.npy") for s in missing[:3])
                raise DataError(f"{self.sequences_dir / sequence}: images without a {what} file: {names}{more}")
        return stems

    def frame_ids(self) -> list[str]:
        if self._ids is None:
            ids, before = [], 0
            for sequence in self.sequences():
                stems = self._stems(sequence)
                for i, stem in enumerate(stems):
                    ids.append(f"{sequence}/{stem}")
                    self._index[ids[-1]] = 2 * (before + i) + (self.conf["camera"] == 3)
                before += len(stems)
            if not ids:
                raise DataError(f"dataset {self.name!r}: no frames for split {self.split!r} under {self.sequences_dir}")
            self._ids = ids
        return list(self._ids)

    def draw_index(self, frame_id: str) -> int:
        """The frame's index in the peers' dataset list over this split's sequences."""
        if frame_id not in self._index:
            self.frame_ids()
        if frame_id not in self._index:
            raise DataError(f"dataset {self.name!r}: frame {frame_id!r} is not in split {self.split!r}")
        return self._index[frame_id]

    def load(self, frame_id: str) -> SensorFrame:
        sequence, sep, stem = frame_id.partition("/")
        if not sep or not sequence or not stem:
            raise DataError(f"dataset {self.name!r}: frame id {frame_id!r} is not of the form 'NN/NNNNNN'")
        images, Ks, clouds = self._dirs(sequence)
        calib = self.root / "calib" / sequence / "calib.txt"
        K_calib, T = peer_calib(calib, self.conf["camera"])
        image_path = images / f"{stem}.npy"
        image = read_image(image_path)
        self._same_size(image_path, image)
        K = read_K(Ks / f"{stem}.npy", K_calib, calib)
        check_fits(image_path, image, K, Ks / f"{stem}.npy")
        points = read_points(clouds / f"{stem}.npy")
        return SensorFrame(
            dataset=RECORDING,
            frame_id=frame_id,
            image=image,
            points=points,
            ring=np.zeros(len(points), np.int16),
            K=K,
            T_cam_lidar=T,
            match_radius_px=self.match_radius_px,
            source=str(clouds / f"{stem}.npy"),
            draw_index=self.draw_index(frame_id),
            preprocessed=True,
        )

    def _same_size(self, path: Path, image: np.ndarray) -> None:
        """A KITTI sequence has one image size: an image of another size is another sequence's frame."""
        first = path.parent / "000000.npy"  # the loaders number a sequence's frames from 0
        if first == path or not first.is_file():
            return
        shape = npy_files.header(first)[0]
        if image.shape != shape:
            raise DataError(f"{path}: a {image.shape[1]} x {image.shape[0]} image where this sequence's are "
                            f"{shape[1]} x {shape[0]} ({first.name}): an image of another sequence?")  # fmt: skip

    def identity(self) -> dict[str, Any]:
        return {**super().identity(), "camera": self.conf["camera"], "sequences": self.conf["sequences"]}

    def frame_files(self, frame_id: str) -> list[Path]:
        sequence, _, stem = frame_id.partition("/")
        images, Ks, clouds = self._dirs(sequence)
        return [images / f"{stem}.npy", Ks / f"{stem}.npy", clouds / f"{stem}.npy",
                self.root / "calib" / sequence / "calib.txt"]  # fmt: skip
