"""Write the preprocessed KITTI layout CorrI2P, CoFiI2P and ICL read, from the original KITTI Odometry download.

Its download links keep dying (CorrI2P #8, #10, #21; CoFiI2P #1, #22) and the scripts that made it are partly
unpublished, so i2pbench makes it from `sequences/NN/{velodyne, image_2, image_3, calib.txt}`:

    calib/NN/calib.txt                         the sequence's calib.txt, byte for byte
    sequences/NN/img_P2/NNNNNN.npy             [H x W x 3] uint8 RGB, the full-size image_2 PNG (image_3: img_P3)
    sequences/NN/K_P2/NNNNNN.npy               [3 x 3] float32, P2's left 3 x 3 (P3: K_P3)
    sequences/NN/pc_npy_with_normal/NNNNNN.npy [7 x N] float32 rows x, y, z (LiDAR frame, m), reflectance,
                                               surface normal x, y, z (LiDAR frame, unit, z >= 0)

The cloud is made as DeepI2P's data/kitti/kitti_pc_bin_to_npy_with_downsample_sn.py makes it (CorrI2P's
kitti_script/ copy): Open3D's voxel grid of 0.1 m, normals by a hybrid search (radius 0.6 m, at most 30 neighbours)
oriented to +z, each voxel's reflectance that of the raw return nearest to it (SciPy's cKDTree, 1-NN). The image is
DeepI2P's data/kitti_png_to_npy.py's: OpenCV's BGR decode flipped to RGB. docs/datasets.md says what the scripts
leave unclear and what was chosen.
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..layers.peer_inputs import estimate_up_normals, open3d_voxels
from .images import read_image
from .kitti import _parse_calib, sequence_stems

POINTS_DIR = "pc_npy_with_normal"


@dataclass
class ExportSummary:
    """What an export wrote: frames per sequence, bytes and seconds, for the command's closing line."""

    frames: dict[str, int] = field(default_factory=dict)
    bytes: int = 0
    seconds: float = 0.0

    @property
    def total(self) -> int:
        return sum(self.frames.values())


def read_scan(path: Path) -> np.ndarray:
    """[N x 4] float32 of a KITTI .bin as the scripts read it (struct 'ffff'; reflectance not clipped)."""
    if not path.is_file():
        raise DataError(f"{path}: LiDAR scan not found")
    size = path.stat().st_size
    if size % 16 or size == 0:
        raise DataError(f"{path}: {size} bytes is not a positive multiple of 16 (float32 x, y, z, reflectance)")
    scan = np.fromfile(path, dtype="<f4").reshape(-1, 4)
    if not np.isfinite(scan).all():
        raise DataError(f"{path}: the scan holds NaN or inf values")
    return scan


def _grid(scan: np.ndarray):
    """Open3D's 0.1 m voxel grid of a scan (the point cloud object, for normals) and each voxel point's reflectance,
    the nearest raw return's."""
    from scipy.spatial import cKDTree

    down = open3d_voxels(scan[:, :3])
    _, nearest = cKDTree(scan[:, :3]).query(np.asarray(down.points), k=1)
    return down, scan[nearest, 3]


def grid_points(scan: np.ndarray) -> np.ndarray:
    """[V x 4] float32 x, y, z, reflectance: the preprocessed cloud without its normals, as the layout stores it."""
    down, reflectance = _grid(scan)
    return np.column_stack([np.asarray(down.points), reflectance]).astype(np.float32)


def points_with_normals(scan: np.ndarray) -> np.ndarray:
    """[7 x V] float32: the voxel grid's points, their nearest raw return's reflectance and their +z normals."""
    down, reflectance = _grid(scan)
    estimate_up_normals(down)
    xyz, normals = np.asarray(down.points), np.asarray(down.normals)
    return np.concatenate([xyz.T, reflectance[None], normals.T], axis=0).astype(np.float32)


def intrinsics(calib: Path, camera: int) -> np.ndarray:
    """[3 x 3] float32: P{camera}'s left 3 x 3, as the loaders' KittiCalibHelper keeps it."""
    values = _parse_calib(calib, (f"P{camera}",)).get(f"P{camera}")
    if values is None or values.size != 12:
        raise DataError(f"{calib}: no P{camera} line of 12 numbers")
    return values.reshape(3, 4)[:, :3].astype(np.float32)


def _save(path: Path, array: np.ndarray) -> int:
    np.save(path, np.ascontiguousarray(array))
    return path.stat().st_size


def export_sequence(source: Path, out: Path, progress: Callable[[str], None] | None = None) -> tuple[int, int]:
    """Export one sequence directory; returns (frames, bytes written)."""
    name = source.name
    calib = source / "calib.txt"
    if not calib.is_file():
        raise DataError(f"{calib}: calibration file not found")
    (out / "calib" / name).mkdir(parents=True, exist_ok=True)
    shutil.copyfile(calib, out / "calib" / name / "calib.txt")
    cameras = [c for c in (2, 3) if (source / f"image_{c}").is_dir()]
    stems = sequence_stems(source, 2)
    _check_numbering(source, stems)
    dirs = [POINTS_DIR] + [f"{kind}_P{c}" for c in cameras for kind in ("img", "K")]
    for d in dirs:
        (out / "sequences" / name / d).mkdir(parents=True, exist_ok=True)
    written = 0
    for stem in stems:
        seq_out = out / "sequences" / name
        cloud = points_with_normals(read_scan(source / "velodyne" / f"{stem}.bin"))
        written += _save(seq_out / POINTS_DIR / f"{stem}.npy", cloud)
        for c in cameras:
            written += _save(seq_out / f"img_P{c}" / f"{stem}.npy", read_image(source / f"image_{c}" / f"{stem}.png"))
            written += _save(seq_out / f"K_P{c}" / f"{stem}.npy", intrinsics(calib, c))
        if progress:
            progress(f"{name}/{stem}")
    return len(stems), written


def _check_numbering(source: Path, stems: list[str]) -> None:
    """The loaders name frame i `%06d.npy` for i in range(count): refuse a sequence numbered otherwise."""
    expected = [f"{i:06d}" for i in range(len(stems))]
    if stems != expected:
        odd = next(s for s, e in zip(stems, expected, strict=True) if s != e)
        raise DataError(f"{source}: frames must be numbered 000000 up without gaps, as the loaders count them "
                        f"(found {odd} where {expected[stems.index(odd)]} belongs)")  # fmt: skip


def export_kitti(source_root: Path, out_root: Path, sequences: list[str] | None = None,
                 progress: Callable[[str], None] | None = None) -> ExportSummary:  # fmt: skip
    """Export every sequence (or those named) under `source_root/sequences` to `out_root` in the CorrI2P layout."""
    base = Path(source_root) / "sequences"
    if not base.is_dir():
        raise DataError(f"{base} not found (the KITTI Odometry root must hold sequences/NN/...)")
    names = sorted(p.name for p in base.iterdir() if p.is_dir()) if sequences is None else list(sequences)
    absent = [str(base / n) for n in names if not (base / n).is_dir()]
    if absent:
        raise DataError(f"sequences not found: {', '.join(absent)}")
    summary, start = ExportSummary(), time.perf_counter()
    for name in names:
        frames, written = export_sequence(base / name, Path(out_root), progress)
        summary.frames[name] = frames
        summary.bytes += written
    summary.seconds = time.perf_counter() - start
    return summary
