"""What one plugin registered, as `i2pbench plugins` lists it: names by kind, each class's `module:Class` (nothing
imported), aliases and methods; every list read off the registry's tables."""

from __future__ import annotations

import os

from .catalog import CLASS_KINDS, Registry
from .methods import Method

IN_ORDER = ("protocol", "weights")  # listed in the order registered; every other kind by name


def components_of(registry: Registry, plugin: str) -> dict[str, list[str]]:
    """What one plugin registered, by kind (shipped weights by file name)."""
    out: dict[str, list[str]] = {}
    for kind, table in registry.tables.items():
        names = table.names_of(plugin)
        names = names if kind in IN_ORDER else sorted(names)
        if names:
            out[kind] = [os.path.basename(n) for n in names] if kind == "weights" else names
    return out


def paths_of(registry: Registry, plugin: str) -> dict[str, dict[str, str]]:
    """Each of the plugin's components, datasets and corruptions by kind: name -> `module:Class` (nothing imported),
    one hop from a name typed on the command line to its code."""
    return {
        kind: {name: registry.path(kind, name) for name in names}
        for kind, names in components_of(registry, plugin).items()
        if kind in CLASS_KINDS
    }


def aliases_of(registry: Registry, plugin: str) -> dict[str, dict[str, list[str]]]:
    """The other names of the plugin's components, by kind: name -> [aliases]."""
    out = {kind: table.aliases_of(plugin) for kind, table in registry.tables.items()}
    return {kind: aliases for kind, aliases in out.items() if aliases}


def methods_of(registry: Registry, plugin: str) -> list[Method]:
    return [registry.methods[name] for name in registry.methods.names_of(plugin)]
