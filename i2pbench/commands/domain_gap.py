"""`i2pbench domain-gap`: statistics of two datasets side by side (e.g. the synthetic set against real KITTI)."""

from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path
from typing import Any

from .options import add_data_options, open_dataset, positive_int, yaml_setting

DECILES = (10, 50, 90)
# the table's rows, in order (i2pbench.diagnostics.domain_gap computes them); docs/diagnose.md says the same
STATISTICS = {
    "frames": "frames summarised (no std)",
    **{f"{n}_pixels": f"{n} edge pixels per image, uncapped" for n in ("lsd", "canny")},
    **{f"{n}_points": f"{n} edge points per scan, uncapped" for n in ("depth", "reflectance", "depth+reflectance")},
    "ratio_in_fov": "diagnose's ratio_in_fov for lsd x depth+reflectance (default caps, the dataset's eps_c)",
    "coverage2d": "diagnose's coverage2d for that pair: the chance level",
    "lift": "diagnose's lift for that pair: ratio_in_fov / coverage2d",
    "points": "LiDAR points per scan",
    "in_fov": "share of a scan's points that project into the image under the true pose",
    **{f"range_q{q}": f"{q}th percentile of the points' ranges (m, sensor distance)" for q in DECILES},
    "range_over_40m": "share of points farther than 40 m",
    **{f"reflectance_q{q}": f"{q}th percentile of the points' reflectance (in [0, 1])" for q in DECILES},
    "reflectance_zero": "share of points with reflectance exactly 0",
    "rings": "distinct laser rings in the scan (Frame.ring), as the dataset reads or recovers them",
    "grey_mean": "mean grey level of the image (0-255, OpenCV's RGB -> grey)",
    "grey_std": "standard deviation of the grey levels within the image",
    "gradient_mean": "mean 3x3 Sobel gradient magnitude sqrt(dx^2 + dy^2) of the grey image",
    "gradient_q90": "90th percentile of that magnitude",
    "strong_gradient": "share of pixels whose magnitude exceeds --gradient-threshold (default 150, sobel's)",
}
OUT_SUFFIXES = (".csv", ".md")


def epilog(width: int = 100) -> str:
    """The statistics glossary, one aligned entry per row of the table (as `diagnose --help` lists its columns)."""
    indent = " " * (max(map(len, STATISTICS)) + 4)
    entries = [
        textwrap.fill(meaning, width, initial_indent=f"  {name:<{len(indent) - 2}}", subsequent_indent=indent)
        for name, meaning in STATISTICS.items()
    ]
    head = "statistics (one row each; mean and std over frames;\n  ratio = mean / against mean, difference = mean - "
    return f"{head}against mean):\n" + "\n".join(entries)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "domain-gap",
        help="edge, LiDAR and image statistics of two datasets side by side",
        epilog=epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_data_options(p)
    p.add_argument("--against", required=True, help="the dataset to compare with (kitti, nuscenes, synthetic, ...)")
    p.add_argument("--against-split", default="test")
    p.add_argument("--against-root", help="its root directory (else I2PBENCH_<NAME>_ROOT)")
    p.add_argument("--against-conf", action="append", default=[], type=yaml_setting, metavar="KEY=VALUE")
    p.add_argument("--against-frames", type=positive_int, help="its first N frames (default: --frames)")
    p.add_argument("--gradient-threshold", type=float, default=150.0, help="strong_gradient's Sobel threshold")
    p.add_argument("--seed", type=int, default=0, help="protocol seed (its transform moves no statistic)")
    p.add_argument("--out", help="also write the table here, as CSV (.csv) or Markdown (.md)")


def against_args(args: argparse.Namespace) -> argparse.Namespace:
    """The --against-* options as the data options `open_dataset` reads."""
    return argparse.Namespace(
        dataset=args.against,
        split=args.against_split,
        data_root=args.against_root,
        data_conf=args.against_conf,
        frames=args.against_frames or args.frames,
    )


def labels(a: argparse.Namespace, b: argparse.Namespace) -> tuple[str, str]:
    """`name/split` for each side; the roots' folder names, then '(against)', tell two equal ones apart."""
    first, second = f"{a.dataset}/{a.split}", f"{b.dataset}/{b.split}"
    if first == second:
        first, second = (f"{first} ({Path(x.data_root or x.dataset).name})" for x in (a, b))
    return (first, f"{second} (against)") if first == second else (first, second)


def chosen_frames(registry: Any, args: argparse.Namespace) -> tuple[Any, list[str]]:
    """The dataset and its first --frames ids; listing them is what finds a bad root, before any work is done."""
    from ..errors import DataError

    dataset = open_dataset(registry, args)
    ids = dataset.frame_ids()[: args.frames]
    if not ids:
        raise DataError(f"dataset {args.dataset!r} split {args.split!r} has no frames")
    return dataset, ids


def run(args: argparse.Namespace) -> int:
    from ..data.skipping import loaded_frames
    from ..diagnostics.domain_gap import gap_extractors, side_by_side, summarize_frames, to_markdown
    from ..errors import I2PBenchError
    from ..registry.build import default_registry
    from ..scoring.protocol import Protocol

    if args.out and Path(args.out).suffix not in OUT_SUFFIXES:
        raise I2PBenchError(f"--out {args.out}: expected a .csv or .md file")
    registry, other = default_registry(), against_args(args)
    sides = [chosen_frames(registry, ns) for ns in (args, other)]
    extractors, protocol = gap_extractors(registry), Protocol(seed=args.seed)
    summaries = [
        summarize_frames(loaded_frames(dataset, ids, protocol, "domain-gap"), extractors, args.gradient_threshold)
        for dataset, ids in sides
    ]
    table = side_by_side(*summaries, labels(args, other))
    print(to_markdown(table))
    if args.out:
        write(table, Path(args.out))
    return 0


def write(table: Any, path: Path) -> None:
    """CSV or Markdown by the suffix; an unwritable path is one error line (the table is already printed)."""
    from ..diagnostics.domain_gap import to_markdown
    from ..errors import I2PBenchError

    text = to_markdown(table) + "\n" if path.suffix == ".md" else table.to_csv(index=False, na_rep="nan")
    try:
        path.write_text(text)
    except OSError as exc:
        raise I2PBenchError(f"--out {path}: could not write the table ({exc.strerror or exc})") from None
    print(f"written: {path}", file=sys.stderr)
