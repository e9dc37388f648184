"""Proof against the authors' code for the nuScenes layouts: build a devkit dataroot (v1.0-test) from the real
scene-0916 keyframes, export it with i2pbench to CoFiI2P's and CorrI2P's nuScenes layouts, run each peer's own
nuScenes dataset class on its layout (scripts/peer_nuscenes_loader.py, from the checkout, in a process of its own)
and compare what it returns with what i2pbench hands the stages under that peer's card, frame by frame.

    python scripts/nuscenes_layout_check.py --cofii2p /work/peers/CoFiI2P --corri2p /work/peers/CorrI2P \
        --records ../shared/data/nuscenes_real --out docs/results/nuscenes-layout-check.json

The keyframe records hold no sweeps, so the export is made with the build scripts' two thresholds off (45000 points,
6000 in the image: one sweep has ~34,000 returns); each frame is then one sweep (docs/datasets.md).

With --cofii2p it also runs CoFiI2P's own build scripts (scripts/peer_nuscenes_build.py) and compares their files
with i2pbench's export, file by file: on the same keyframes with their sample_data records chained in time (as if
consecutive sweeps) and accumulation_frame_skip 1, so that the scripts' thresholds are met as published (4-7 sweeps
a frame). CorrI2P's make_dataset.py cannot run (it imports DeepI2P modules absent from its repository and saves
nothing), so its files are checked through its loader only.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from layout_check import compare, head, run_loader

from i2pbench.data.nuscenes_dataroot import build_dataroot
from i2pbench.data.peer_nuscenes import INTENSITY_MAX, CoFiI2PNuScenes, CorrI2PNuScenes
from i2pbench.data.peer_nuscenes_export import export_nuscenes
from i2pbench.scoring import cards

LOADER = Path(__file__).with_name("peer_nuscenes_loader.py")
BUILD = Path(__file__).with_name("peer_nuscenes_build.py")
BUILD_FOLDERS = ("pc", "img", "ext", "int")
# per array, the largest difference allowed. The image and K: the same arrays resized and cropped by the same
# OpenCV call (0, 1e-6 px). The points: their float64 (CoFiI2P) or float32 (CorrI2P) product against i2pbench's same
# product handed on as float32 (a float32 rounding of coordinates up to ~80 m: 1e-5 m). Intensity: i2pbench's
# frames hold it / 255 in float32 (1e-7). P: their float32 inverse of the float32 P_random against i2pbench's float64
# one (entries up to ~14: 1e-5).
TOLERANCES = {"image": 0.0, "K": 1e-6, "points_xyz": 1e-5, "intensity": 1e-7, "P": 1e-5}
DATASETS = {"cofii2p": CoFiI2PNuScenes, "corri2p": CorrI2PNuScenes}
CARDS = {"cofii2p": cards.COFII2P, "corri2p": cards.CORRI2P}


def check(peer: str, checkout: Path, export: Path, scratch: Path) -> dict:
    """Compare one peer's loader with i2pbench on every frame of its layout's export."""
    dataset = DATASETS[peer]("test", {"root": str(export)})
    indices = sorted(dataset.draw_index(f) for f in dataset.frame_ids())
    theirs = run_loader(LOADER, peer, checkout, export, indices, scratch / f"{peer}.npz")

    def item(index: int) -> dict:  # the loader's arrays are named "<array>_<index>"
        return {key: theirs[f"{key}_{index}"] for key in ("image", "K", "points", "P")}

    protocol = CARDS[peer].protocol(0, dataset.name)
    return compare(dataset, protocol, item, TOLERANCES, "intensity", INTENSITY_MAX)


def export_both(records: Path, scratch: Path) -> dict[str, dict]:
    """The dataroot and each layout's export (thresholds off: keyframes without sweeps), with size and time."""
    build_dataroot([records], scratch / "dataroot", "v1.0-test")
    made = {}
    for peer in DATASETS:
        start = time.perf_counter()
        summary = export_nuscenes(scratch / "dataroot", scratch / peer, f"{peer}-nuscenes", min_points=0,
                                  min_in_image=0)  # fmt: skip
        seconds = round(time.perf_counter() - start, 2)
        made[peer] = {"frames": summary.frames, "bytes": summary.bytes, "seconds": seconds,
                      "sweeps": sorted(set(summary.sweeps))}  # fmt: skip
    return made


def chain_sweeps(dataroot: Path, version: str) -> None:
    """Link each channel's sample_data records in time order, as the tables of a dataroot with sweeps link them."""
    path = dataroot / version / "sample_data.json"
    rows = json.loads(path.read_text())
    channels: dict[str, list[dict]] = {}
    for row in rows:
        channels.setdefault(row["filename"].split("/")[1], []).append(row)
    for records in channels.values():
        records.sort(key=lambda r: r["timestamp"])
        for earlier, later in zip(records, records[1:], strict=False):
            earlier["next"], later["prev"] = later["token"], earlier["token"]
    path.write_text(json.dumps(rows))


def check_build(checkout: Path, records: Path, scratch: Path) -> dict:
    """CoFiI2P's build scripts against i2pbench's export on the chained keyframes: names, dtypes, shapes, values."""
    root = scratch / "build"
    build_dataroot([records], root / "test", "v1.0-test")
    chain_sweeps(root / "test", "v1.0-test")
    command = [sys.executable, str(BUILD), str(checkout), str(root), str(scratch / "theirs"), "1"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=900, cwd=BUILD.parent)
    if done.returncode:
        raise RuntimeError(f"CoFiI2P's build scripts failed:\n{done.stderr[-3000:]}")
    summary = export_nuscenes(root / "test", scratch / "mine", "cofii2p-nuscenes", accumulate_skip=1)
    files, worst = [], {folder: 0.0 for folder in BUILD_FOLDERS}
    for folder in BUILD_FOLDERS:
        theirs, mine = scratch / "theirs" / "test" / folder, scratch / "mine" / "test" / folder
        names = sorted(p.name for p in theirs.iterdir())
        if names != sorted(p.name for p in mine.iterdir()):
            worst[folder] = float("inf")
        for name in names:
            a, b = np.load(theirs / name), np.load(mine / name) if (mine / name).is_file() else None
            same = b is not None and a.dtype == b.dtype and a.shape == b.shape
            diff = float(np.abs(a.astype(np.float64) - b.astype(np.float64)).max()) if same else float("inf")
            worst[folder] = max(worst[folder], diff)
            files.append({"file": f"{folder}/{name}", "dtype": str(a.dtype), "shape": list(a.shape), "diff": diff})
    return {"files": files, "largest": worst, "frames": summary.frames, "sweeps": summary.sweeps,
            "dropped": summary.dropped, "met": {k: v == 0.0 for k, v in worst.items()}}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cofii2p", type=Path, help="CoFiI2P checkout (WHU-USI3DV/CoFiI2P)")
    parser.add_argument("--corri2p", type=Path, help="CorrI2P checkout (rsy6318/CorrI2P)")
    parser.add_argument("--records", type=Path, required=True, help="nuScenes record folders (shared/data)")
    parser.add_argument("--out", type=Path, help="record to write (JSON)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        scratch = Path(tmp)
        exports = export_both(args.records, scratch)
        record = {"records": str(args.records), "exports": exports, "tolerances": TOLERANCES, "peers": {}}
        for peer in DATASETS:
            checkout = getattr(args, peer)
            if checkout is not None:
                record["peers"][peer] = {"checkout": str(checkout), "commit": head(checkout),
                                         **check(peer, checkout, scratch / peer, scratch)}  # fmt: skip
            if peer == "cofii2p" and checkout is not None:
                record["build"] = {
                    "peer": peer,
                    "commit": head(checkout),
                    **check_build(checkout, args.records, scratch),
                }
    text = json.dumps(record, indent=1)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    checks = [*record["peers"].values(), *([record["build"]] if "build" in record else [])]
    return 0 if all(all(c["met"].values()) for c in checks) else 1


if __name__ == "__main__":
    sys.exit(main())
