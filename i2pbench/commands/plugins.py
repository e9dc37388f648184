"""`i2pbench plugins`: every installed plugin, its version, and the components it registers (or why it failed)."""

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
            "status": "failed" if i.failed else "ok",
            "error": i.error,
            "hooks": list(i.hooks),
            "components": components_of(registry, i.name),
        }
        for i in registry.plugins
    ]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    for row in rows:
        failed = f" FAILED: {row['error']}" if row["error"] else ""
        print(f"{row['plugin']} {row['version']} ({row['distribution']}){failed}")
        for kind, names in row["components"].items():
            print(f"  {kind:12s} {', '.join(names)}")
    return 0
