"""KITTI Odometry: `sequences/NN/{velodyne/NNNNNN.bin, image_2/NNNNNN.png, image_3/, calib.txt, times.txt}`, and
the ground-truth poses `poses/NN.txt` where the benchmark gives them (sequences 00-10).

`read_frame` reads one frame from any directory in this layout, so the synthetic dataset (which writes the same
layout) shares the reader, its checks and its error messages. Where a sequence has its poses file, a frame carries the
LiDAR's ego motion (`SensorFrame.ego_motion`), from its neighbours' poses; without one it is None.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..errors import DataError
from ..types import SensorFrame
from .base import Dataset
from .calibration import check_finite, check_intrinsics, check_rotation
from .ego_motion import around
from .images import check_fits, read_image
from .scanlines import recover_rings

SPLIT_SEQUENCES: dict[str, tuple[str, ...]] = {
    "trainval": tuple(f"{i:02d}" for i in range(9)),  # 00-08, as CorrI2P, DeepI2P, VP2P-Match and EdgeRegNet train
    "train": tuple(f"{i:02d}" for i in range(8)),  # 00-07: trainval less the validation sequence
    "val": ("08",),  # drawn from 00-08 by whole sequence (frames 0.1 s apart would leak), never from 09-10
    "test": ("09", "10"),
}
BENCHMARK_SEQUENCES = frozenset(f"{i:02d}" for i in range(22))  # KITTI Odometry's 00-21
FRAME_PERIOD_S = 0.1  # KITTI's scans come at 10 Hz: the frame times of a sequence without times.txt


def _parse_calib(path: Path, needed: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The `KEY: numbers` lines of a calib.txt. Comments and lines that are no key are skipped, and so is a key of
    other values (`calib_time: 09-Jan-2012 13:57:47`) unless it is `needed`; a key given twice is an error."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: not a text calibration file (byte {exc.start} is not UTF-8 text)") from exc
    out: dict[str, np.ndarray] = {}
    seen: dict[str, int] = {}
    for lineno, line in enumerate(text.splitlines(), 1):
        key, sep, values = line.partition(":")
        key = key.strip()
        if not sep or not key.isidentifier():
            continue
        if key in seen:
            raise DataError(f"{path}:{lineno}: a second {key} line (the first is line {seen[key]}); keep one")
        seen[key] = lineno
        try:
            out[key] = np.array([float(v) for v in values.split()], dtype=np.float64)
        except ValueError as exc:
            if key in needed:
                raise DataError(f"{path}:{lineno}: {key} holds a non-number ({exc})") from exc
    return out


@lru_cache(maxsize=64)
def _calib_cached(path: str, mtime_ns: int, camera: int) -> tuple[np.ndarray, np.ndarray]:
    calib = _parse_calib(Path(path), (f"P{camera}", "Tr"))
    mats = {}
    for key in (f"P{camera}", "Tr"):
        if key not in calib:
            raise DataError(f"{path}: no {key} line (needed for camera {camera})")
        if calib[key].size != 12:
            raise DataError(f"{path}: {key} has {calib[key].size} values, expected 12 (a 3x4 matrix)")
        check_finite(calib[key], path, key)
        mats[key] = calib[key].reshape(3, 4)
    P = mats[f"P{camera}"]
    K = P[:, :3].copy()
    check_intrinsics(K, f"{path}: P{camera}")
    check_rotation(mats["Tr"][:, :3], path, "the rotation of Tr")
    T = np.eye(4)
    T[:3, :] = mats["Tr"]
    # Pc = K [I | b]: the baseline b of camera c relative to rectified camera 0 goes into the extrinsic.
    T[:3, 3] += np.linalg.solve(K, P[:, 3])
    return K, T


def camera_calib(calib_path: Path, camera: int) -> tuple[np.ndarray, np.ndarray]:
    """(K [3 x 3], T_cam_lidar [4 x 4]) for camera `camera`, so that K @ T_cam_lidar @ X == Pc @ [Tr; 0 0 0 1] @ X."""
    if not calib_path.is_file():
        raise DataError(f"{calib_path}: calibration file not found")
    K, T = _calib_cached(str(calib_path), calib_path.stat().st_mtime_ns, camera)
    return K.copy(), T.copy()


def _numbers(path: Path, per_line: int) -> np.ndarray:
    """[n x per_line] float64 of a text file of numbers, one record a line; a bad line is an error naming it."""
    rows = []
    for lineno, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        if not line.strip():
            continue
        try:
            row = [float(v) for v in line.split()]
        except ValueError as exc:
            raise DataError(f"{path}:{lineno}: not a number ({exc})") from exc
        if len(row) != per_line or not np.isfinite(row).all():
            raise DataError(f"{path}:{lineno}: expected {per_line} finite numbers, got {line.strip()[:80]!r}")
        rows.append(row)
    return np.array(rows, dtype=np.float64).reshape(-1, per_line)


@lru_cache(maxsize=16)
def _lidar_poses_cached(poses: str, calib: str, times: str | None, stamps: tuple) -> tuple[np.ndarray, np.ndarray]:
    """(world <- LiDAR [n x 4 x 4], times [n] s) of a sequence; `stamps` (the files' mtimes) key the cache."""
    rows = _numbers(Path(poses), 12)
    cam0 = np.tile(np.eye(4), (len(rows), 1, 1))
    cam0[:, :3, :] = rows.reshape(-1, 3, 4)
    for i, pose in enumerate(cam0):
        check_rotation(pose[:3, :3], f"{poses}:{i + 1}", "the pose's rotation")
    tr = np.eye(4)
    tr[:3, :] = _tr(Path(calib))
    frame_times = _numbers(Path(times), 1)[:, 0] if times else np.arange(len(rows)) * FRAME_PERIOD_S
    if len(frame_times) < len(rows):
        raise DataError(f"{times}: {len(frame_times)} times for the {len(rows)} poses of {poses}")
    return cam0 @ tr, frame_times[: len(rows)]  # the poses are camera 0's; Tr maps the LiDAR into camera 0


def _tr(calib_path: Path) -> np.ndarray:
    calib = _parse_calib(calib_path, ("Tr",))
    if "Tr" not in calib or calib["Tr"].size != 12:
        raise DataError(f"{calib_path}: no Tr line of 12 numbers (needed with the sequence's poses)")
    return calib["Tr"].reshape(3, 4)


def poses_file(sequence_dir: Path) -> Path:
    """Where KITTI keeps a sequence's ground-truth poses: `<root>/poses/<sequence>.txt`."""
    return sequence_dir.parent.parent / "poses" / f"{sequence_dir.name}.txt"


def ego_motion(sequence_dir: Path, stem: str) -> np.ndarray | None:
    """[6] the LiDAR's velocity (v m/s, w rad/s, in its frame) at frame `stem`, from the neighbouring frames' poses
    (frame times from times.txt, else 10 Hz); None when the sequence has no poses file."""
    poses = poses_file(sequence_dir)
    if not poses.is_file():
        return None
    calib, times = sequence_dir / "calib.txt", sequence_dir / "times.txt"
    has_times = times.is_file()
    stamps = tuple(p.stat().st_mtime_ns for p in (poses, calib, *([times] if has_times else [])))
    lidar, frame_times = _lidar_poses_cached(str(poses), str(calib), str(times) if has_times else None, stamps)
    if not stem.isdigit() or int(stem) >= len(lidar):
        raise DataError(f"{poses}: {len(lidar)} poses, none for frame {stem} (its line is the frame's number + 1)")
    return around(lidar, frame_times, int(stem))


def read_points(path: Path) -> np.ndarray:
    """[N x 4] float32 x, y, z, reflectance in [0, 1] from a KITTI .bin."""
    if not path.is_file():
        raise DataError(f"{path}: LiDAR scan not found")
    size = path.stat().st_size
    if size % 16 or size == 0:
        raise DataError(f"{path}: {size} bytes is not a positive multiple of 16 (float32 x, y, z, reflectance)")
    points = np.fromfile(path, dtype=np.float32).reshape(-1, 4)
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise DataError(
            f"{path}: {int(bad.sum())} of {len(points)} points hold NaN or inf (first at row {bad.argmax()})"
        )
    points[:, 3] = np.clip(points[:, 3], 0.0, 1.0)
    return points


def read_frame(
    sequence_dir: Path, stem: str, camera: int = 2, dataset: str = "kitti", match_radius_px: float = 3.0
) -> SensorFrame:
    """Read frame `stem` of a sequence directory in the KITTI Odometry layout; frame id is "<sequence>/<stem>"."""
    sequence_dir = Path(sequence_dir)
    scan = sequence_dir / "velodyne" / f"{stem}.bin"
    points = read_points(scan)
    K, T = camera_calib(sequence_dir / "calib.txt", camera)
    image_path = sequence_dir / f"image_{camera}" / f"{stem}.png"
    image = read_image(image_path)
    check_fits(image_path, image, K, sequence_dir / "calib.txt")
    return SensorFrame(
        dataset=dataset,
        frame_id=f"{sequence_dir.name}/{stem}",
        image=image,
        points=points,
        ring=recover_rings(points),
        K=K,
        T_cam_lidar=T,
        match_radius_px=match_radius_px,
        source=str(scan),
        ego_motion=ego_motion(sequence_dir, stem),
    )


def _missing(stems: set[str], folder: Path, suffix: str) -> str:
    names = sorted(stems)
    more = f" and {len(names) - 5} more" if len(names) > 5 else ""
    return ", ".join(str(folder / f"{s}{suffix}") for s in names[:5]) + more


def _refuse_other_case(folder: Path, suffix: str) -> None:
    """A `.BIN` or `.Png` would be skipped by the listing, silently losing its frame: an error naming it instead."""
    odd = sorted(p.name for p in folder.glob("*") if p.suffix.lower() == suffix and p.suffix != suffix)
    if odd:
        more = f" and {len(odd) - 3} more" if len(odd) > 3 else ""
        raise DataError(
            f"{folder / odd[0]}{more}: KITTI names these files *{suffix}, in lower case; rename them (not read as is)"
        )


def sequence_stems(sequence_dir: Path, camera: int = 2) -> list[str]:
    """Sorted frame stems of a sequence, after checking every scan has its image and every image its scan."""
    velodyne, images = sequence_dir / "velodyne", sequence_dir / f"image_{camera}"
    _refuse_other_case(velodyne, ".bin")
    _refuse_other_case(images, ".png")
    scans = {p.stem for p in velodyne.glob("*.bin")}
    if not scans:
        raise DataError(f"{velodyne}: empty sequence (no .bin scans)")
    pngs = {p.stem for p in images.glob("*.png")}
    if scans - pngs:
        raise DataError(f"{sequence_dir}: scans without an image: missing {_missing(scans - pngs, images, '.png')}")
    if pngs - scans:
        raise DataError(f"{sequence_dir}: images without a scan: missing {_missing(pngs - scans, velodyne, '.bin')}")
    return sorted(scans)


class KittiOdometry(Dataset):
    """KITTI Odometry by sequence: trainval = 00-08 (what the peers train on), split into train = 00-07 and val = 08
    plus any sequence outside the benchmark's 00-21 (e.g. a raw drive: kitti_real's 26); test = 09-10; "all" = every
    sequence on disk."""

    name = "kitti"
    splits = ("train", "val", "trainval", "test", "all")
    default_conf: ClassVar[dict[str, Any]] = {
        "root": None,  # folder holding sequences/; None reads I2PBENCH_KITTI_ROOT
        "camera": 2,  # 2 (left colour) or 3 (right colour)
        "sequences": None,  # explicit list of sequences, overriding the split; each must exist
    }
    match_radius_px = 3.0

    def __init__(self, split: str, conf: dict[str, Any] | None = None) -> None:
        super().__init__(split, conf)
        if self.conf["camera"] not in (2, 3):
            raise DataError(f"dataset 'kitti': camera must be 2 or 3, got {self.conf['camera']!r}")
        self._ids: list[str] | None = None
        self._index: dict[str, int] | None = None

    @property
    def sequences_dir(self) -> Path:
        path = self.root / "sequences"
        if not path.is_dir():
            raise DataError(f"{path} not found (KITTI Odometry root must hold sequences/NN/...)")
        return path

    def sequences(self) -> list[str]:
        """Sequences of this split that exist on disk (an explicit `sequences` conf must all exist)."""
        base = self.sequences_dir
        if self.conf["sequences"] is not None:
            names = [f"{int(s):02d}" if str(s).isdigit() else str(s) for s in self.conf["sequences"]]
            absent = [str(base / n) for n in names if not (base / n).is_dir()]
            if absent:
                raise DataError(f"dataset 'kitti': requested sequences not found: {', '.join(absent)}")
            return sorted(set(names))
        on_disk = sorted(p.name for p in base.iterdir() if p.is_dir())
        if self.split == "all":
            return on_disk
        extra = [s for s in on_disk if s not in BENCHMARK_SEQUENCES] if self.split == "val" else []
        return [s for s in SPLIT_SEQUENCES[self.split] if (base / s).is_dir()] + extra

    def frame_ids(self) -> list[str]:
        if self._ids is None:
            camera = self.conf["camera"]
            ids = [f"{s}/{stem}" for s in self.sequences() for stem in sequence_stems(self.sequences_dir / s, camera)]
            if not ids:
                raise DataError(f"dataset 'kitti': no frames for split {self.split!r} under {self.sequences_dir}")
            self._ids = ids
        return list(self._ids)

    def load(self, frame_id: str) -> SensorFrame:
        sequence, sep, stem = frame_id.partition("/")
        if not sep or not sequence or not stem:
            raise DataError(f"dataset 'kitti': frame id {frame_id!r} is not of the form 'NN/NNNNNN'")
        frame = read_frame(self.sequences_dir / sequence, stem, self.conf["camera"], self.name, self.match_radius_px)
        return dataclasses.replace(frame, draw_index=self.draw_index(frame_id))

    def draw_index(self, frame_id: str) -> int | None:
        """The frame's index in the peers' loaders' list over this split (2 x its position, + 1 for camera 3), for
        the cards that follow their loaders (i2pbench.scoring.protocol_peer); None for a frame outside the split."""
        if self._index is None:
            camera3 = self.conf["camera"] == 3
            self._index = {frame: 2 * i + camera3 for i, frame in enumerate(self.frame_ids())}
        return self._index.get(frame_id)

    def identity(self) -> dict[str, Any]:
        return {**super().identity(), "camera": self.conf["camera"], "sequences": self.conf["sequences"]}

    @staticmethod
    def layout_files(sequence_dir: Path, stem: str, camera: int = 2) -> list[Path]:
        """The files `read_frame` reads for frame `stem` of a sequence: scan, image and the sequence's calibration,
        plus its poses and times where a poses file exists (without one, the list, and so cache keys, are as before
        ego motion was read)."""
        scan, image = sequence_dir / "velodyne" / f"{stem}.bin", sequence_dir / f"image_{camera}" / f"{stem}.png"
        poses = poses_file(sequence_dir)
        motion = [poses, sequence_dir / "times.txt"] if poses.is_file() else []
        return [scan, image, sequence_dir / "calib.txt", *motion]

    def frame_files(self, frame_id: str) -> list[Path]:
        sequence, _, stem = frame_id.partition("/")
        return self.layout_files(self.sequences_dir / sequence, stem, self.conf["camera"])
