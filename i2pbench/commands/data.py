"""`i2pbench data synth`: generate the embedded synthetic dataset (KITTI Odometry layout) ahead of time."""

from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("data", help="dataset utilities")
    data_sub = p.add_subparsers(dest="data_command", required=True)
    synth = data_sub.add_parser("synth", help="generate the synthetic street dataset in the KITTI Odometry layout")
    synth.add_argument("--root", help="output directory (default: the synthetic dataset's cache directory)")
    synth.add_argument("--train", type=int, default=None, help="frames in the train split")
    synth.add_argument("--val", type=int, default=None, help="frames in the val split")
    synth.add_argument("--test", type=int, default=None, help="frames in the test split")
    synth.add_argument("--seed", type=int, default=0)
    synth.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    synth.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from ..data.synthetic.dataset import SyntheticStreets, generate

    frames = dict(SyntheticStreets.default_conf["frames"])
    frames.update({k: v for k, v in (("train", args.train), ("val", args.val), ("test", args.test)) if v is not None})
    root = generate(args.root, frames["train"], frames["val"], frames["test"], seed=args.seed, workers=args.workers)
    print(f"synthetic dataset ready at {root} ({frames})", file=sys.stderr)
    return 0
