"""`i2pbench diagnose`: edge-quality diagnostics for extractor pairs (the paper's Table III, without training)."""

from __future__ import annotations

import argparse
import sys
import textwrap

from .options import add_data_options, open_dataset, split_list

COLUMNS = {  # the summary's columns, shown by --help; docs/diagnose.md says the same at more length
    "frames": "frames diagnosed",
    "n2d, n3d": "2D and 3D keypoints per frame",
    "n3d_in_fov": "3D keypoints that project into the image under the true pose",
    "ratio_in_fov": "share of those within eps_c (--radius) px of a 2D keypoint: the most a matcher can recover, "
    "and a training loss's positives (the paper wants over 10%)",
    "ratio_in_fov_pooled": "the same pooled over frames: all matched / all in the image",
    "ratio_all": "matched 3D keypoints over all 3D keypoints, in the image or not",
    "coverage2d": "share of image pixels within eps_c of a 2D keypoint: the ratio_in_fov of 3D points scattered at "
    "random (chance)",
    "lift": "ratio_in_fov / coverage2d, the gain over chance; above 1 even for random 3D points (the LiDAR sees "
    "part of the image only), so compare with --extractor3d random",
    "frames_over_target": "share of frames whose ratio_in_fov exceeds the paper's 10%",
    "time2d_ms, time3d_ms": "median extraction time per frame",
}


def epilog(width: int = 100) -> str:
    """The column glossary, one aligned entry per column, wrapped here (argparse would run it into one paragraph)."""
    indent = " " * (max(map(len, COLUMNS)) + 4)
    entries = [
        textwrap.fill(meaning, width, initial_indent=f"  {name:<{len(indent) - 2}}", subsequent_indent=indent)
        for name, meaning in COLUMNS.items()
    ]
    return "columns (one row per extractor pair; means over frames unless said otherwise):\n" + "\n".join(entries)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose",
        help="share of 3D edge points within eps_c of a 2D edge pixel, per extractor pair",
        epilog=epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--extractor", "--extractor2d", dest="extractor2d", type=split_list, default=["lsd"])
    p.add_argument("--extractor3d", type=split_list, default=["depth+reflectance"])
    p.add_argument("--radius", type=float, default=None, help="eps_c in pixels (default: the dataset's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="write the per-pair summary as CSV here")
    add_data_options(p)


def run(args: argparse.Namespace) -> int:
    import pandas as pd

    from ..data.skipping import loaded_frames
    from ..diagnostics.edges import edge_diagnostics_grid, summarize_edge_diagnostics
    from ..errors import I2PBenchError
    from ..registry.build import default_registry
    from ..scoring.protocol import Protocol

    registry = default_registry()
    dataset = open_dataset(registry, args)
    protocol = Protocol(seed=args.seed)
    frames = loaded_frames(dataset, dataset.frame_ids()[: args.frames], protocol, "diagnose")  # bad ones skipped
    e2 = [registry.component("extractor2d", n)() for n in args.extractor2d]
    e3 = [registry.component("extractor3d", n)() for n in args.extractor3d]
    summary = summarize_edge_diagnostics(edge_diagnostics_grid(frames, e2, e3, args.radius))
    with pd.option_context("display.width", 200, "display.max_columns", 30, "display.precision", 3):
        print(summary.to_string(index=False))
    if args.out:
        try:
            summary.to_csv(args.out, index=False)
        except OSError as exc:
            raise I2PBenchError(f"--out {args.out}: could not write the summary ({exc.strerror or exc})") from None
        print(f"written: {args.out}", file=sys.stderr)
    return 0
