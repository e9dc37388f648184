"""Loading the plugins of the `i2pbench` entry-point group into a pluggy manager.

Environment variables (as llm's LLM_LOAD_PLUGINS):
- I2PBENCH_LOAD_PLUGINS: comma-separated entry-point names; when set, only these are loaded ("" loads none).
- I2PBENCH_BLOCK_PLUGINS: comma-separated entry-point names never to load.

A plugin that fails to import is skipped, with a warning, and listed as failed (`strict=True` raises instead): one
broken third-party package must not take every command down with it, `i2pbench plugins` included.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from typing import Any

import pluggy

from ..errors import PluginError
from . import hookspecs
from .entry_points import EntryPoint, installed

ENTRY_POINT_GROUP = "i2pbench"
BUILTIN_DISTRIBUTION = "i2pbench"  # the reference plugins ship in i2pbench's own distribution
Registration = tuple[tuple[Any, ...], dict[str, Any]]  # one `register(...)` call's arguments


@dataclass(frozen=True)
class PluginInfo:
    name: str
    version: str
    distribution: str
    hooks: tuple[str, ...]
    error: str = ""  # why the plugin was skipped; "" when it loaded

    @property
    def failed(self) -> bool:
        return bool(self.error)


def _env_names(var: str) -> set[str] | None:
    value = os.environ.get(var)
    if value is None:
        return None
    return {part.strip() for part in value.split(",") if part.strip()}


def plugin_selection() -> tuple[str | None, str | None]:
    """the environment's say over which plugins load (I2PBENCH_LOAD_PLUGINS, I2PBENCH_BLOCK_PLUGINS), as set."""
    return os.environ.get("I2PBENCH_LOAD_PLUGINS"), os.environ.get("I2PBENCH_BLOCK_PLUGINS")


def selected_entry_points() -> list[EntryPoint]:
    """the group's entry points in name order, less those the environment variables leave out."""
    only = _env_names("I2PBENCH_LOAD_PLUGINS")
    blocked = _env_names("I2PBENCH_BLOCK_PLUGINS") or set()
    eps = sorted(installed(ENTRY_POINT_GROUP), key=lambda ep: ep.name)
    return [ep for ep in eps if ep.name not in blocked and (only is None or ep.name in only)]


def _hooks_of(plugin: object) -> tuple[str, ...]:
    return tuple(h for h in hookspecs.HOOK_NAMES if callable(getattr(plugin, h, None)))


def make_plugin_manager(
    extra_plugins: tuple[object, ...] = (), strict: bool = False
) -> tuple[pluggy.PluginManager, list[PluginInfo]]:
    """Load entry-point plugins (honouring the environment filters) plus `extra_plugins` (used by tests).

    One that fails to import is reported and listed with its error (or, `strict`, raises PluginError)."""
    pm = pluggy.PluginManager(ENTRY_POINT_GROUP)
    pm.add_hookspecs(hookspecs)
    infos = []
    for ep in selected_entry_points():
        try:
            plugin = ep.load()
            pm.register(plugin, name=ep.name)
        except (Exception, SystemExit) as exc:  # a broken third-party plugin must not take the tool down with it
            error = f"failed to import (entry point {ep.name} = {ep.value}): {type(exc).__name__}: {exc}"
            if strict:
                raise PluginError(f"plugin {ep.name!r} {error}") from exc
            warn(ep.name, error)
            infos.append(PluginInfo(ep.name, ep.version, ep.distribution, (), error))
            continue
        infos.append(PluginInfo(ep.name, ep.version, ep.distribution, _hooks_of(plugin)))
    for plugin in extra_plugins:
        name = getattr(plugin, "__name__", type(plugin).__name__)
        pm.register(plugin, name=name)
        infos.append(PluginInfo(name, "local", "local", _hooks_of(plugin)))
    return pm, infos


def warn(plugin: str, problem: str) -> None:
    print(
        f"i2pbench: warning: plugin {plugin!r} {problem}; it is skipped "
        f"(I2PBENCH_BLOCK_PLUGINS={plugin} silences this warning)",
        file=sys.stderr,
    )


def plugin_alone(plugin: object, name: str) -> pluggy.PluginManager:
    """A plugin manager holding only `plugin`: its hooks, called through pluggy, call that plugin alone, so what they
    register is attributed to it. (pluggy's subset_hook_caller would do on the shared manager, but it hashes every
    other plugin, and a plugin object need not be hashable.)"""
    pm = pluggy.PluginManager(ENTRY_POINT_GROUP)
    pm.add_hookspecs(hookspecs)
    pm.register(plugin, name=name)
    return pm


def registrations(alone: pluggy.PluginManager, hook: str) -> list[Registration]:
    """What the one plugin `alone` holds registers from one hook: each `register(...)` call's arguments."""
    out: list[Registration] = []
    getattr(alone.hook, hook)(register=lambda *args, **kwargs: out.append((args, kwargs)))
    return out
