"""`i2pbench plugins`: every installed plugin, its version, and the components it registers."""

from __future__ import annotations

import argparse
import json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plugins", help="list installed plugins and the components they register")
    p.add_argument("--json", action="store_true")


def run(args: argparse.Namespace) -> int:
    from ..plugins import components_of, default_registry

    registry = default_registry()
    rows = [
        {
            "plugin": i.name,
            "version": i.version,
            "distribution": i.distribution,
            "hooks": list(i.hooks),
            "components": components_of(registry, i.name),
        }
        for i in registry.plugins
    ]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for row in rows:
        print(f"{row['plugin']} {row['version']} ({row['distribution']})")
        for kind, names in row["components"].items():
            print(f"  {kind:12s} {', '.join(names)}")
    return 0
