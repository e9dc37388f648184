"""`i2pbench data`: dataset utilities.

`synth` generates the embedded synthetic dataset (KITTI Odometry layout) ahead of time; `nuscenes-dataroot` turns
nuScenes record folders (as in shared/data) into a devkit dataroot that `--dataset nuscenes` reads; `export` writes
a preprocessed layout the field shares (commands/data_export.py).
"""

from __future__ import annotations

import argparse
import sys

from . import data_export


def frame_count(text: str) -> int:
    """An argparse type: a split's frame count, 0 or more (`--train -1` made the default 400)."""
    try:
        count = int(text)
    except ValueError:
        count = -1
    if count < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not 0 or a positive integer")
    return count


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("data", help="dataset utilities")
    data_sub = p.add_subparsers(dest="data_command", required=True)
    synth = data_sub.add_parser("synth", help="generate the synthetic street dataset in the KITTI Odometry layout")
    synth.add_argument("--root", help="output directory (default: the synthetic dataset's cache directory)")
    synth.add_argument("--train", type=frame_count, default=None, help="frames in the train split")
    synth.add_argument("--val", type=frame_count, default=None, help="frames in the val split")
    synth.add_argument("--test", type=frame_count, default=None, help="frames in the test split")
    synth.add_argument("--seed", type=int, default=0)
    synth.add_argument(
        "--style",
        default="default",
        help="generator style: default, or kitti (image tone and texture, clutter and reflectance fitted to real "
        "KITTI); a style other than the default has its own cache directory",
    )
    synth.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    synth.add_argument("--quiet", action="store_true", help="no progress bar")
    nus = data_sub.add_parser("nuscenes-dataroot", help="build a nuScenes devkit dataroot from record folders")
    nus.add_argument("--records", nargs="+", required=True, metavar="DIR", help="record folders, or folders of them")
    nus.add_argument("--out", required=True, metavar="ROOT", help="dataroot to write; its version folder must be new")
    nus.add_argument("--version", default="v1.0-trainval", help="table folder to write (v1.0-test for test scenes)")
    nus.add_argument("--copy", action="store_true", help="copy the sensor files instead of linking them")
    data_export.add_parser(data_sub)


def run(args: argparse.Namespace) -> int:
    if args.data_command == "nuscenes-dataroot":
        return nuscenes_dataroot(args)
    if args.data_command == "export":
        return data_export.run(args)
    from ..data.synthetic.dataset import SyntheticStreets, generate
    from ..errors import I2PBenchError, os_problem

    frames = dict(SyntheticStreets.default_conf["frames"])
    frames.update({k: v for k, v in (("train", args.train), ("val", args.val), ("test", args.test)) if v is not None})
    try:
        root = generate(
            args.root, frames["train"], frames["val"], frames["test"], args.seed, args.workers, style=args.style
        )
    except OSError as exc:
        where = f"--root {args.root}" if args.root else "(the cache folder; --root chooses another)"
        raise I2PBenchError(f"data synth {where}: could not write the frames: {os_problem(exc)}") from None
    style = "" if args.style == "default" else f", style {args.style}; use --data-conf style={args.style}"
    print(f"synthetic dataset ready at {root} ({frames}{style})", file=sys.stderr)
    return 0


def nuscenes_dataroot(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..data.nuscenes import VERSIONS
    from ..data.nuscenes_dataroot import build_dataroot
    from ..errors import DataError, os_problem

    if args.version not in VERSIONS:
        raise DataError(f"--version {args.version!r}: choose one of {list(VERSIONS)}")
    try:
        sizes = build_dataroot([Path(d) for d in args.records], Path(args.out), args.version, copy=args.copy)
    except OSError as exc:
        raise DataError(f"data nuscenes-dataroot --out {args.out}: could not write it: {os_problem(exc)}") from None
    print(
        f"nuScenes dataroot ready at {args.out}: {args.version} with {sizes['sample']} sample(s) of "
        f"{sizes['scene']} scene(s); use --dataset nuscenes --data-root {args.out}",
        file=sys.stderr,
    )
    return 0
