"""Writes synthetic frames in the KITTI Odometry layout: sequences/NN/{velodyne/NNNNNN.bin, image_2/NNNNNN.png,
calib.txt}. Each frame is an independent scene seeded by (seed, sequence, index), so frames can be produced in any
order, by any number of processes, with byte-identical results; they are made in pinned processes (pinned.py), so
the bytes are the same on every machine too.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ...execution.progress import bar
from . import pinned
from .camera import render
from .lidar import scan
from .raycast import Caster
from .rig import calib_text, camera2, hdl64, on_uneven_road
from .scene import build_scene
from .style import DEFAULT, Style, style_rng
from .version import SCENE_DRAWS


def frame_rng(seed: int, sequence: str, index: int) -> np.random.Generator:
    return np.random.default_rng([SCENE_DRAWS, int(seed), int(sequence), int(index)])


def simulate(seed: int, sequence: str, index: int, style: Style = DEFAULT) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(points [N x 4] float32, ring [N] int16, image [H x W x 3] uint8 RGB) of one frame, made in a pinned process:
    the bytes written to the dataset's files."""
    return pinned.run(simulate_here, [(seed, sequence, index, 0, style)])[0]


def simulate_here(
    seed: int, sequence: str, index: int, nthreads: int = 0, style: Style = DEFAULT
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`simulate` in this process, with whatever kernels its CPU and environment select (what a pinned worker runs)."""
    rng = frame_rng(seed, sequence, index)
    extra = style_rng(style, SCENE_DRAWS, seed, int(sequence), index)
    caster = Caster(build_scene(rng, style, extra), nthreads=nthreads)
    lidar = on_uneven_road(hdl64(), rng)
    points, ring, _ = scan(caster, lidar, rng, style)
    return points, ring, render(caster, camera2(), lidar.pose, rng, style)


def write_frame(sequence_dir: Path, seed: int, index: int, nthreads: int = 0, style: Style = DEFAULT) -> None:
    """Simulate and write frame `index` of the sequence directory (named by its two-digit sequence number), in this
    process (a pinned worker's job)."""
    sequence_dir = Path(sequence_dir)
    points, _, image = simulate_here(seed, sequence_dir.name, index, nthreads, style)
    stem = f"{index:06d}"
    points.astype("<f4").tofile(sequence_dir / "velodyne" / f"{stem}.bin")
    if not cv2.imwrite(str(sequence_dir / "image_2" / f"{stem}.png"), image[:, :, ::-1]):
        raise OSError(f"could not write {sequence_dir / 'image_2' / f'{stem}.png'}")


def write_sequence(
    sequence_dir: Path, n_frames: int, seed: int, workers: int | None = None, style: Style = DEFAULT
) -> None:
    """All frames of one sequence plus its calib.txt; frames are spread over `workers` pinned processes (one ray
    caster thread each when there are several)."""
    sequence_dir = Path(sequence_dir)
    for sub in ("velodyne", "image_2"):
        (sequence_dir / sub).mkdir(parents=True, exist_ok=True)
    (sequence_dir / "calib.txt").write_text(calib_text())
    workers = max(1, min(workers or os.cpu_count() or 1, n_frames))
    nthreads = 0 if workers == 1 else 1
    calls = [(sequence_dir, seed, index, nthreads, style) for index in range(n_frames)]
    with bar(n_frames, f"synthesising {sequence_dir.name}") as progress:
        pinned.run(write_frame, calls, workers, progress.update)


def generate_kitti(
    out_dir: Path, sequences: dict[str, int], seed: int = 0, workers: int | None = None, style: Style = DEFAULT
) -> Path:
    """Write sequences (two-digit name -> number of frames) under out_dir/sequences; returns out_dir."""
    out_dir = Path(out_dir)
    for sequence, n_frames in sequences.items():
        write_sequence(out_dir / "sequences" / f"{int(sequence):02d}", n_frames, seed, workers, style)
    return out_dir
