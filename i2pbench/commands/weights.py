"""`i2pbench weights import NAME FILE --out W.pt`: another code base's checkpoint as an i2pbench checkpoint, mapped
by the importer NAME a method declares (e.g. `edgeregnet-official`: the EdgeRegNet authors' `KITTI.t7`)."""

from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("weights", help="import another code base's checkpoint as an i2pbench checkpoint")
    actions = p.add_subparsers(dest="action", required=True)
    imp = actions.add_parser("import", help="map a foreign checkpoint's keys onto a method size's stages")
    imp.add_argument("importer", help="importer name, declared by a method (i2pbench plugins lists them)")
    imp.add_argument("source", help="the foreign checkpoint file")
    imp.add_argument(
        "--out",
        required=True,
        help="the i2pbench checkpoint to write (use it with --weights), outside the installed packages; never the "
        "source file or a file of another kind",
    )
    imp.add_argument("--force", action="store_true", help="replace an existing i2pbench checkpoint at --out")


def run(args: argparse.Namespace) -> int:
    from ..registry.build import default_registry
    from ..weights.checkpoints import import_weights, load_checkpoint

    path = import_weights(default_registry(), args.importer, args.source, args.out, args.force)
    checkpoint = load_checkpoint(path)
    origin = checkpoint.meta["imported_from"]
    print(
        f"{path}: {checkpoint.identity}, trained on {checkpoint.trained_on}; from {origin['file']} "
        f"(sha256 {origin['sha256']})",
        file=sys.stderr,
    )
    return 0
