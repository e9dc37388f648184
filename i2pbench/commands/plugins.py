"""`i2pbench plugins`: every installed plugin, its version, and what it registers (or why it failed).

Each component is shown with its `module:Class`, one hop from a name typed on the command line to its code (read
from the registration: nothing is imported), and each method with its stages, sizes, presets and weights.
"""

from __future__ import annotations

import argparse
from typing import Any

NAMED = ("preset", "weights", "method")  # listed by name: they have no module of their own


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plugins", help="list installed plugins and the components they register")
    p.add_argument("--json", action="store_true")


def run(args: argparse.Namespace) -> int:
    from ..registry.build import default_registry

    registry = default_registry()
    rows = [_row(registry, info) for info in registry.plugins]
    if args.json:
        import json

        print(json.dumps(rows, indent=2))
        return 0
    for row in rows:
        print("\n".join(_lines(row)))
    return 0


def _row(registry: Any, info: Any) -> dict[str, Any]:
    from ..registry.listing import aliases_of, components_of, methods_of, paths_of

    return {
        "plugin": info.name,
        "version": info.version,
        "distribution": info.distribution,
        "status": "failed" if info.failed else "ok",
        "error": info.error,
        "hooks": list(info.hooks),
        "components": components_of(registry, info.name),
        "modules": paths_of(registry, info.name),
        "aliases": aliases_of(registry, info.name),
        "methods": [m.describe() for m in methods_of(registry, info.name)],
    }


def _lines(row: dict[str, Any]) -> list[str]:
    """The plugin's header, a line per component (name, module, aliases), then its methods, presets and weights."""
    failed = f" FAILED: {row['error']}" if row["error"] else ""
    lines = [f"{row['plugin']} {row['version']} ({row['distribution']}){failed}"]
    width = max((len(n) for paths in row["modules"].values() for n in paths), default=0)
    for kind, paths in row["modules"].items():
        for i, (name, path) in enumerate(paths.items()):
            aliases = row["aliases"].get(kind, {}).get(name)
            also = f"  (alias: {', '.join(aliases)})" if aliases else ""
            lines.append(f"  {kind if i == 0 else '':12s} {name:{width}s}  {path}{also}")
    for method in row["methods"]:
        lines += _method_lines(method)
    declared = {what: {n for m in row["methods"] for n in m[what]} for what in ("presets", "weights")}
    for kind, what in (("preset", "presets"), ("weights", "weights"), ("protocol", "")):
        plain = [n for n in row["components"].get(kind, []) if n not in declared.get(what, ())]
        if plain:
            lines.append(f"  {kind:12s} {', '.join(plain)}")
    return lines


def _method_lines(method: dict[str, Any]) -> list[str]:
    """The method's name and description, its stages, a line per size (its row label when not its name), its
    presets and weights."""
    lines = [f"  {'method':12s} {method['name']}  {method['description']}".rstrip()]
    lines.append(f"    {'stages':10s} {' > '.join(n for n in method['stages'].values() if n != 'none')}")
    width = max(len(name) for name in method["sizes"])
    for name, size in method["sizes"].items():
        label = size["variant"]
        note = "" if label == name else f"; rows labelled ({label})" if label else "; rows unlabelled"
        lines.append(f"    {'size':10s} {name:{width}s}  {size['description']}{note}".rstrip())
    aliases = method["preset_aliases"]
    presets = [f"{p} (alias: {', '.join(aliases[p])})" if p in aliases else p for p in method["presets"]]
    for what, names in (("presets", presets), ("weights", method["weights"])):
        if names:
            lines.append(f"    {what:10s} {', '.join(names)}")
    return lines
