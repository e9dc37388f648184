"""What the two proofs against the authors' loaders share (corri2p_layout_check.py on KITTI, nuscenes_layout_check.py
on nuScenes): running a peer's loader script in a process of its own, the largest difference per array between its
item and i2pbench's frame, the comparison over every frame against the tolerances, and the checkout's commit."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np


def run_loader(loader: Path, peer: str, checkout: Path, root: Path, indices: list[int], out: Path) -> dict:
    """the `loader` script's items for the dataset indices, as arrays of its .npz `out`; its error if it fails. It
    runs in its own folder (so it imports its siblings), every path made absolute first."""
    paths = [str(p.resolve()) for p in (checkout, root, out)]
    command = [sys.executable, str(loader.resolve()), peer, *paths, *map(str, indices)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=900, cwd=loader.parent)
    if done.returncode:
        raise RuntimeError(f"{peer}'s loader failed:\n{done.stderr[-3000:]}")
    return dict(np.load(out))


def differences(theirs: Mapping[str, np.ndarray], frame, channel: str, scale: float = 1.0) -> dict[str, float]:
    """The largest difference per array between a loader's item and i2pbench's frame; the points' fourth column is
    `channel` ("reflectance", "intensity"), theirs divided by `scale` to be i2pbench's."""
    points = theirs["points"]
    if points.shape != frame.points.shape:
        return {"points_shape": float("inf")}
    return {
        "image": float(np.abs(theirs["image"].astype(int) - frame.image.astype(int)).max()),
        "K": float(np.abs(theirs["K"] - frame.K).max()),
        "points_xyz": float(np.abs(points[:, :3] - frame.points[:, :3]).max()),
        channel: float(np.abs(points[:, 3] / scale - frame.points[:, 3]).max()),
        "P": float(np.abs(theirs["P"] - frame.T_gt).max()),
    }


def compare(
    dataset,
    protocol,
    item: Callable[[int], dict[str, np.ndarray]],
    tolerances: Mapping[str, float],
    channel: str,
    scale: float = 1.0,
) -> dict:
    """every frame of `dataset` under `protocol` against the loader's `item(index)`: a row per frame, the largest
    difference per array over them, and whether each is within its tolerance."""
    frames = {dataset.draw_index(f): f for f in dataset.frame_ids()}
    rows = []
    for index, frame_id in sorted(frames.items()):
        frame = protocol.apply(dataset.load(frame_id))
        found = differences(item(index), frame, channel, scale)
        rows.append({"frame": frame_id, "index": index, "points": len(frame.points), **found})
    worst = {k: max(r.get(k, float("inf")) for r in rows) for k in tolerances}
    return {"frames": rows, "largest": worst, "met": {k: worst[k] <= tolerances[k] for k in tolerances}}


def head(checkout: Path) -> str:
    """The checkout's commit (the cards cite rsy6318/CorrI2P@4f4a755 and WHU-USI3DV/CoFiI2P@ed90edf)."""
    done = subprocess.run(["git", "-C", str(checkout), "rev-parse", "HEAD"], capture_output=True, text=True)
    return done.stdout.strip() or "unknown (not a git checkout)"
