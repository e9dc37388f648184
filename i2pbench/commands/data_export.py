"""`i2pbench data export --layout corri2p`: write the preprocessed layout the field trains and tests on from the
original KITTI Odometry download (i2pbench.data.corri2p_export), so a dead download link stops no one; `--layout
cofii2p-nuscenes` or `corri2p-nuscenes`: those papers' nuScenes layouts from a devkit dataroot
(i2pbench.data.peer_nuscenes_export)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

NUSCENES_LAYOUTS = ("cofii2p-nuscenes", "corri2p-nuscenes")
LAYOUTS = ("corri2p", *NUSCENES_LAYOUTS)


def add_parser(data_sub: argparse._SubParsersAction) -> None:
    p = data_sub.add_parser(
        "export",
        help="write a preprocessed layout (corri2p: CorrI2P, CoFiI2P, ICL) from KITTI, or a peer's nuScenes one",
    )
    p.add_argument("--layout", required=True, choices=LAYOUTS, help="the layout to write (docs/datasets.md)")
    p.add_argument(
        "--from",
        dest="source",
        required=True,
        metavar="ROOT",
        help="the original KITTI Odometry root (holding sequences/NN/{velodyne,image_2,calib.txt}); for a nuScenes "
        "layout, the devkit dataroot (holding v1.0-*/ and samples/, sweeps/)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="folder to write calib/ and sequences/ into")
    p.add_argument("--sequences", nargs="+", metavar="NN", help="sequences to export (default: every one)")
    p.add_argument("--quiet", action="store_true", help="no line per frame")
    nus = p.add_argument_group("nuScenes layouts (the build scripts' thresholds; docs/datasets.md)")
    nus.add_argument("--version", help="the dataroot's table folder, when it holds several (v1.0-trainval -> train/, "
                     "v1.0-test -> test/)")  # fmt: skip
    nus.add_argument("--min-points", type=int, default=None, metavar="N",
                     help="drop a frame whose accumulated cloud has fewer points, before or after its voxel grid "
                     "(default 45000, the scripts', made for 7 accumulated sweeps)")  # fmt: skip
    nus.add_argument(
        "--min-in-image",
        type=int,
        default=None,
        metavar="N",
        help="drop a frame with no more points projecting into its image (default 6000, the scripts')",
    )


def run(args: argparse.Namespace) -> int:
    from ..errors import I2PBenchError

    nuscenes = {"--version": args.version, "--min-points": args.min_points, "--min-in-image": args.min_in_image}
    given = [flag for flag, value in (*nuscenes.items(), ("--sequences", args.sequences)) if value is not None]
    wrong = [f for f in given if (f == "--sequences") == (args.layout in NUSCENES_LAYOUTS)]
    if wrong:
        raise I2PBenchError(f"data export --layout {args.layout}: {', '.join(wrong)} belongs to the other source "
                            "(--sequences to KITTI's corri2p; --version, --min-points, --min-in-image to "
                            "nuScenes)")  # fmt: skip
    if args.layout in NUSCENES_LAYOUTS:
        return run_nuscenes(args)
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


def run_nuscenes(args: argparse.Namespace) -> int:
    from ..data import peer_nuscenes_export as export
    from ..errors import DataError, os_problem

    def progress(frame: str) -> None:
        if not args.quiet:
            print(f"exported {frame}", file=sys.stderr)

    limits = {"min_points": export.MIN_POINTS if args.min_points is None else args.min_points,
              "min_in_image": export.MIN_IN_IMAGE if args.min_in_image is None else args.min_in_image}  # fmt: skip
    try:
        summary = export.export_nuscenes(Path(args.source), Path(args.out), args.layout, args.version, **limits,
                                         progress=progress)  # fmt: skip
    except OSError as exc:
        raise DataError(f"data export --out {args.out}: could not write it: {os_problem(exc)}") from None
    dropped = "; ".join(f"{n} dropped: {why}" for why, n in summary.dropped.items())
    sweeps = f", {min(summary.sweeps)}-{max(summary.sweeps)} sweep(s) a frame" if summary.sweeps else ""
    n = max(summary.frames, 1)
    print(f"{args.layout} layout ready at {args.out}/{summary.folder}: {summary.frames} frame(s){sweeps}, "
          f"{summary.bytes / 1e6:.1f} MB ({summary.bytes / 1e6 / n:.2f} MB and {summary.seconds / n:.2f} s a frame)"
          f"{'; ' + dropped if dropped else ''}; use --dataset {args.layout} --data-root {args.out}",
          file=sys.stderr)  # fmt: skip
    if not summary.frames and summary.dropped:
        print(
            "i2pbench: note: every frame was dropped by the build scripts' thresholds, made for 7 accumulated "
            "sweeps; a dataroot without sweeps needs lower ones (--min-points, --min-in-image)",
            file=sys.stderr,
        )
    return 0
