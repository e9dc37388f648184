"""Loading plugins from the `i2pbench` entry-point group and the name -> component registry built from them.

Environment variables (as llm's LLM_LOAD_PLUGINS):
- I2PBENCH_LOAD_PLUGINS: comma-separated entry-point names; when set, only these are loaded ("" loads none).
- I2PBENCH_BLOCK_PLUGINS: comma-separated entry-point names never to load.

A plugin that fails to import, whose hooks raise, or whose registrations are refused (a name another plugin took,
a class that is no component) is skipped whole, with a warning, and listed as failed: one broken third-party
package must not take every command down with it, `i2pbench plugins` included. The built-in plugins register first,
so a clash with one of them skips the newcomer and keeps the built-in; between two others the one loaded later
(entry points in name order) is skipped. `strict=True` raises instead, for tests and plugin authors.
"""

from __future__ import annotations

import difflib
import importlib.metadata
import os
import sys
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import pluggy

from . import hookspecs
from .components import STAGE_BASES, Component
from .data.base import Dataset
from .errors import PluginError

hookimpl = pluggy.HookimplMarker("i2pbench")
ENTRY_POINT_GROUP = "i2pbench"
BUILTIN_DISTRIBUTION = "i2pbench"  # the reference plugins ship in i2pbench's own distribution


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


@dataclass(frozen=True)
class Preset:
    name: str
    combinations: tuple[dict[str, str], ...]
    description: str
    plugin: str


@dataclass
class Registry:
    """Every component, dataset, preset and shipped checkpoint the loaded plugins registered."""

    components: dict[str, dict[str, tuple[type[Component], str]]] = field(
        default_factory=lambda: {kind: {} for kind in STAGE_BASES}
    )
    datasets: dict[str, tuple[type[Dataset], str]] = field(default_factory=dict)
    presets: dict[str, Preset] = field(default_factory=dict)
    weights: list[tuple[str, str]] = field(default_factory=list)  # (path, plugin)
    plugins: list[PluginInfo] = field(default_factory=list)

    def component(self, kind: str, name: str) -> type[Component]:
        if kind not in self.components:
            raise PluginError(f"unknown stage kind {kind!r}; kinds are {list(self.components)}")
        return self.components[kind][_lookup(self.components[kind], name, kind)][0]

    def dataset(self, name: str) -> type[Dataset]:
        return self.datasets[_lookup(self.datasets, name, "dataset")][0]

    def preset(self, name: str) -> Preset:
        return self.presets[_lookup(self.presets, name, "preset")]

    def owner(self, kind: str, name: str) -> str:
        return self.components[kind][name][1]


def _lookup(table: dict[str, Any], name: str, what: str) -> str:
    if name in table:
        return name
    close = difflib.get_close_matches(name, list(table), n=1, cutoff=0.5)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    raise PluginError(f"unknown {what} {name!r}{hint} (known: {', '.join(sorted(table)) or 'none'})")


def _env_names(var: str) -> set[str] | None:
    value = os.environ.get(var)
    if value is None:
        return None
    return {part.strip() for part in value.split(",") if part.strip()}


def _selected_entry_points() -> list[importlib.metadata.EntryPoint]:
    only = _env_names("I2PBENCH_LOAD_PLUGINS")
    blocked = _env_names("I2PBENCH_BLOCK_PLUGINS") or set()
    eps = sorted(importlib.metadata.entry_points(group=ENTRY_POINT_GROUP), key=lambda ep: ep.name)
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
    for ep in _selected_entry_points():
        dist = ep.dist
        version, distribution = (dist.version, dist.metadata["Name"]) if dist else ("?", "?")
        try:
            plugin = ep.load()
            pm.register(plugin, name=ep.name)
        except (Exception, SystemExit) as exc:  # a broken third-party plugin must not take the tool down with it
            error = f"failed to import (entry point {ep.name} = {ep.value}): {type(exc).__name__}: {exc}"
            if strict:
                raise PluginError(f"plugin {ep.name!r} {error}") from exc
            _warn(ep.name, error)
            infos.append(PluginInfo(ep.name, version, distribution, (), error))
            continue
        infos.append(PluginInfo(ep.name, version, distribution, _hooks_of(plugin)))
    for plugin in extra_plugins:
        name = getattr(plugin, "__name__", type(plugin).__name__)
        pm.register(plugin, name=name)
        infos.append(PluginInfo(name, "local", "local", _hooks_of(plugin)))
    return pm, infos


def _warn(plugin: str, problem: str) -> None:
    print(
        f"i2pbench: warning: plugin {plugin!r} {problem}; it is skipped "
        f"(I2PBENCH_BLOCK_PLUGINS={plugin} silences this warning)",
        file=sys.stderr,
    )


def _collect(pm: pluggy.PluginManager, plugin: str, hook_name: str) -> list[tuple[Any, ...]]:
    """What one plugin registers from one hook (each plugin is called on its own, so it owns what it registers)."""
    out: list[tuple[Any, ...]] = []
    for impl in getattr(pm.hook, hook_name).get_hookimpls():
        if impl.plugin_name == plugin:
            impl.function(register=lambda *args: out.append(args))
    return out


def _add_component(registry: Registry, kind: str, cls: type, plugin: str) -> None:
    base = STAGE_BASES[kind]
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise PluginError(f"plugin {plugin!r} registered {cls!r} as a {kind}, but it does not subclass {base.__name__}")
    if not cls.name:
        raise PluginError(f"plugin {plugin!r} registered {cls.__name__} without a `name`")
    table = registry.components[kind]
    if cls.name in table and table[cls.name][0] is not cls:
        raise PluginError(
            f"{kind} name {cls.name!r} is registered by both plugin {table[cls.name][1]!r} and {plugin!r}"
        )
    table[cls.name] = (cls, plugin)


def _add_dataset(registry: Registry, cls: type, plugin: str) -> None:
    if not (isinstance(cls, type) and issubclass(cls, Dataset) and cls.name):
        raise PluginError(f"plugin {plugin!r} registered {cls!r} as a dataset; it must subclass Dataset and set name")
    if cls.name in registry.datasets and registry.datasets[cls.name][0] is not cls:
        raise PluginError(
            f"dataset {cls.name!r} is registered by both {registry.datasets[cls.name][1]!r} and {plugin!r}"
        )
    registry.datasets[cls.name] = (cls, plugin)


def _add_preset(registry: Registry, args: tuple[Any, ...], plugin: str) -> None:
    name, combinations, description = (list(args) + [""])[:3]
    if name in registry.presets:
        raise PluginError(f"preset {name!r} is registered by both {registry.presets[name].plugin!r} and {plugin!r}")
    registry.presets[name] = Preset(name, tuple(dict(c) for c in combinations), description, plugin)


def build_registry(extra_plugins: tuple[object, ...] = (), strict: bool = False) -> Registry:
    """The registry of the selected entry-point plugins plus `extra_plugins`, built-ins first; a plugin that fails
    is skipped whole and listed with its error (`strict`: PluginError)."""
    pm, infos = make_plugin_manager(extra_plugins, strict)
    registry = Registry()
    for info in sorted(infos, key=lambda i: i.distribution != BUILTIN_DISTRIBUTION):
        if not info.failed:
            try:
                _register(registry, pm, info.name)
            except (Exception, SystemExit) as exc:
                if strict:
                    raise
                error = str(exc) if isinstance(exc, PluginError) else f"raised {type(exc).__name__}: {exc}"
                _warn(info.name, f"could not register: {error}")
                info = replace(info, error=error)
        registry.plugins.append(info)
    return registry


def _register(registry: Registry, pm: pluggy.PluginManager, plugin: str) -> None:
    """Add everything one plugin registers, or (when any of it is refused) nothing at all."""
    trial = Registry(
        {kind: dict(table) for kind, table in registry.components.items()},
        dict(registry.datasets),
        dict(registry.presets),
        list(registry.weights),
    )
    for kind, hook in hookspecs.STAGE_HOOKS.items():
        for (cls,) in _collect(pm, plugin, hook):
            _add_component(trial, kind, cls, plugin)
    for (cls,) in _collect(pm, plugin, "register_datasets"):
        _add_dataset(trial, cls, plugin)
    for args in _collect(pm, plugin, "register_presets"):
        _add_preset(trial, args, plugin)
    for (path,) in _collect(pm, plugin, "register_weights"):
        trial.weights.append((str(path), plugin))
    registry.components, registry.datasets, registry.presets = trial.components, trial.datasets, trial.presets
    registry.weights = trial.weights


@lru_cache(maxsize=1)
def default_registry() -> Registry:
    """The registry of the installed plugins, built once per process."""
    return build_registry()


def components_of(registry: Registry, plugin: str) -> dict[str, list[str]]:
    """What one plugin registered, by kind (for `i2pbench plugins`)."""
    out: dict[str, list[str]] = {}
    for kind, table in registry.components.items():
        names = sorted(n for n, (_, p) in table.items() if p == plugin)
        if names:
            out[kind] = names
    datasets = sorted(n for n, (_, p) in registry.datasets.items() if p == plugin)
    if datasets:
        out["dataset"] = datasets
    presets = sorted(n for n, p in registry.presets.items() if p.plugin == plugin)
    if presets:
        out["preset"] = presets
    weights = [path for path, p in registry.weights if p == plugin]
    if weights:
        out["weights"] = [os.path.basename(w) for w in weights]
    return out
