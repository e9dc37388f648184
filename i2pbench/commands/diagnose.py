"""`i2pbench diagnose`: edge-quality diagnostics for extractor pairs (the paper's Table III, without training)."""

from __future__ import annotations

import argparse

from .run import _split_list, add_data_options, open_dataset


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("diagnose", help="share of 3D edge points within eps_c of a 2D edge pixel, per extractor pair")
    p.add_argument("--extractor", "--extractor2d", dest="extractor2d", type=_split_list, default=["lsd"])
    p.add_argument("--extractor3d", type=_split_list, default=["depth+reflectance"])
    p.add_argument("--radius", type=float, default=None, help="eps_c in pixels (default: the dataset's)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="write the per-pair summary as CSV here")
    add_data_options(p)


def run(args: argparse.Namespace) -> int:
    import pandas as pd

    from ..diagnostics import edge_diagnostics_grid, summarize_edge_diagnostics
    from ..plugins import default_registry
    from ..protocol import Protocol

    registry = default_registry()
    dataset = open_dataset(registry, args)
    protocol = Protocol(seed=args.seed)
    frames = (protocol.apply(dataset.load(f)) for f in dataset.frame_ids()[: args.frames])
    e2 = [registry.component("extractor2d", n)() for n in args.extractor2d]
    e3 = [registry.component("extractor3d", n)() for n in args.extractor3d]
    summary = summarize_edge_diagnostics(edge_diagnostics_grid(frames, e2, e3, args.radius))
    with pd.option_context("display.width", 200, "display.max_columns", 30, "display.precision", 3):
        print(summary.to_string(index=False))
    if args.out:
        summary.to_csv(args.out, index=False)
    return 0
