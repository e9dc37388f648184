"""Proof against the authors' code: export real KITTI frames to the CorrI2P layout with i2pbench, run CorrI2P's and
CoFiI2P's own dataset classes on the export (scripts/peer_kitti_loader.py, from their checkouts, in a process of
their own) and compare what they return with what i2pbench hands the stages for the same frame and seed.

    python scripts/corri2p_layout_check.py --corri2p /work/peers/CorrI2P --cofii2p /work/peers/CoFiI2P \
        --kitti ../shared/data/kitti_odometry --out docs/results/corri2p-layout-check.json

The loaders read their test split ('val': sequences 09 and 10), so the export's two sequences are shown to them as
09 and 10 through symbolic links; the dataset index of a frame is then the same on both sides.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

from layout_check import compare, head, run_loader

from i2pbench.data.corri2p_export import export_kitti
from i2pbench.data.corri2p_kitti import Corri2PKitti
from i2pbench.scoring import cards

LOADER = Path(__file__).with_name("peer_kitti_loader.py")
# per array, the largest difference allowed: the image and K come out bit-identical, and so do the points (the same
# Open3D grid, numpy draw and float arithmetic on one machine); P is the loaders' float32 inverse of their float32
# P_random against i2pbench's float64 one, so float32 rounding of entries up to ~14 (|t| <= 10 sqrt 2 m): 1e-5
TOLERANCES = {"image": 0.0, "K": 1e-6, "points_xyz": 1e-6, "reflectance": 1e-7, "P": 1e-5}
CARDS = {"corri2p": cards.CORRI2P, "cofii2p": cards.COFII2P}
TEST_SEQUENCES = ("09", "10")


def loader_view(export: Path, view: Path) -> None:
    """`view` shows the export's two sequences as 09 and 10, the loaders' test split."""
    names = sorted(p.name for p in (export / "sequences").iterdir() if p.is_dir())
    if len(names) != 2:
        raise SystemExit(f"{export}: the check needs exactly two sequences (the loaders' 09 and 10), found {names}")
    for kind in ("calib", "sequences"):
        (view / kind).mkdir(parents=True, exist_ok=True)
        for name, shown in zip(names, TEST_SEQUENCES, strict=True):
            (view / kind / shown).symlink_to((export / kind / name).resolve(), target_is_directory=True)


def check(peer: str, checkout: Path, export: Path, scratch: Path) -> dict:
    """Compare one peer's loader with i2pbench on every frame of the export."""
    view = scratch / f"{peer}-view"
    loader_view(export, view)
    dataset = Corri2PKitti("all", {"root": str(export)})
    indices = sorted(dataset.draw_index(f) for f in dataset.frame_ids())
    theirs = run_loader(LOADER, peer, checkout, view, indices, scratch / f"{peer}.npz")

    def item(index: int) -> dict:  # the loader's arrays are named "<index>/<array>"
        return {k.split("/", 1)[1]: v for k, v in theirs.items() if k.split("/", 1)[0] == str(index)}

    return compare(dataset, CARDS[peer].protocol(0, dataset.name), item, TOLERANCES, "reflectance")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--corri2p", type=Path, help="CorrI2P checkout (rsy6318/CorrI2P)")
    parser.add_argument("--cofii2p", type=Path, help="CoFiI2P checkout (WHU-USI3DV/CoFiI2P)")
    parser.add_argument("--kitti", type=Path, required=True, help="KITTI Odometry root with two sequences")
    parser.add_argument("--out", type=Path, help="record to write (JSON)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        scratch = Path(tmp)
        start = time.perf_counter()
        summary = export_kitti(args.kitti, scratch / "export")
        record = {"kitti": str(args.kitti), "frames": summary.total, "export_bytes": summary.bytes,
                  "export_s": round(time.perf_counter() - start, 2), "tolerances": TOLERANCES, "peers": {}}  # fmt: skip
        for peer in ("corri2p", "cofii2p"):
            checkout = getattr(args, peer)
            if checkout is not None:
                record["peers"][peer] = {"checkout": str(checkout), "commit": head(checkout),
                                         **check(peer, checkout, scratch / "export", scratch)}  # fmt: skip
    text = json.dumps(record, indent=1)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 0 if all(all(p["met"].values()) for p in record["peers"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
