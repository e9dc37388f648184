"""`i2pbench data export --layout corri2p`: write the preprocessed layout the field trains and tests on from the
original KITTI Odometry download (i2pbench.data.corri2p_export), so a dead download link stops no one."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

LAYOUTS = ("corri2p",)


def add_parser(data_sub: argparse._SubParsersAction) -> None:
    p = data_sub.add_parser("export", help="write a preprocessed layout (corri2p: CorrI2P, CoFiI2P, ICL) from KITTI")
    p.add_argument("--layout", required=True, choices=LAYOUTS, help="the layout to write (docs/datasets.md)")
    p.add_argument(
        "--from",
        dest="source",
        required=True,
        metavar="ROOT",
        help="the original KITTI Odometry root (holding sequences/NN/{velodyne,image_2,calib.txt})",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="folder to write calib/ and sequences/ into")
    p.add_argument("--sequences", nargs="+", metavar="NN", help="sequences to export (default: every one)")
    p.add_argument("--quiet", action="store_true", help="no line per frame")


def run(args: argparse.Namespace) -> int:
    from ..data.corri2p_export import export_kitti
    from ..errors import DataError, os_problem

    def progress(frame: str) -> None:
        if not args.quiet:
            print(f"exported {frame}", file=sys.stderr)

    names = [f"{int(s):02d}" if s.isdigit() else s for s in args.sequences] if args.sequences else None
    try:
        summary = export_kitti(Path(args.source), Path(args.out), names, progress)
    except OSError as exc:
        raise DataError(f"data export --out {args.out}: could not write it: {os_problem(exc)}") from None
    per_frame = summary.seconds / max(summary.total, 1)
    print(f"{args.layout} layout ready at {args.out}: {summary.total} frame(s) of {len(summary.frames)} sequence(s), "
          f"{summary.bytes / 1e6:.1f} MB ({summary.bytes / 1e6 / max(summary.total, 1):.2f} MB and {per_frame:.2f} s "
          f"a frame); use --dataset corri2p-kitti --data-root {args.out}", file=sys.stderr)  # fmt: skip
    return 0
