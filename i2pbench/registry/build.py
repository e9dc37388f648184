"""Building the registry from the loaded plugins, one plugin at a time and all or nothing.

A plugin whose hooks raise, or whose registrations are refused (a name another plugin took, a class that is no
component), is skipped whole, with a warning, and listed as failed. The built-in plugins register first, so a clash
with one of them skips the newcomer and keeps the built-in; between two others the one loaded later (entry points in
name order) is skipped. `strict=True` raises instead, and imports every class registered by path while registering,
for tests and plugin authors.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache
from typing import Any

import pluggy

from ..errors import PluginError
from ..stages.components import STAGES
from .catalog import CLASS_KINDS, Preset, Registry
from .lazy import registered_class
from .loading import BUILTIN_DISTRIBUTION, make_plugin_manager, plugin_alone, plugin_selection, registrations, warn
from .methods import Method, Row

CLASS_HOOKS: dict[str, str] = {
    **{kind: spec.hook for kind, spec in STAGES.items()},
    "dataset": "register_datasets",
    "corruption": "register_corruptions",
}


def build_registry(extra_plugins: tuple[object, ...] = (), strict: bool = False) -> Registry:
    """The registry of the selected entry-point plugins plus `extra_plugins`, built-ins first; a plugin that fails
    is skipped whole and listed with its error (`strict`: PluginError)."""
    pm, infos = make_plugin_manager(extra_plugins, strict)
    registry = Registry()
    for info in sorted(infos, key=lambda i: i.distribution != BUILTIN_DISTRIBUTION):
        if not info.failed:
            try:
                registry.tables = register_plugin(registry, pm, info.name, strict).tables
            except (Exception, SystemExit) as exc:
                if strict:
                    raise
                error = str(exc) if isinstance(exc, PluginError) else f"raised {type(exc).__name__}: {exc}"
                warn(info.name, f"could not register: {error}")
                info = dataclasses.replace(info, error=error)
        registry.plugins.append(info)
    return registry


def default_registry() -> Registry:
    """The registry of the installed plugins the environment selects, built once per process and selection: a caller
    that sets I2PBENCH_LOAD_PLUGINS for a while (a test, a subcommand) never leaves its registry to the next one."""
    return _registry_for(plugin_selection())


@lru_cache(maxsize=4)
def _registry_for(selection: tuple[str | None, str | None]) -> Registry:
    return build_registry()


def register_plugin(registry: Registry, pm: pluggy.PluginManager, plugin: str, strict: bool = False) -> Registry:
    """A copy of `registry` with everything one plugin registers; any of it refused raises, and `registry` is left
    as it was."""
    trial, alone = registry.copy(), plugin_alone(pm.get_plugin(plugin), plugin)
    for kind in CLASS_KINDS:
        for args, kwargs in registrations(alone, CLASS_HOOKS[kind]):
            aliases = kwargs.pop("aliases", ())
            name, entry = registered_class(kind, plugin, *args, **kwargs)
            trial.tables[kind].add(name, entry, plugin)
            trial.tables[kind].add_aliases(name, aliases, plugin)
            if strict:
                trial.resolve_class(kind, name)
    for args, kwargs in registrations(alone, "register_presets"):
        add_preset(trial, plugin, *args, **kwargs)
    for args, kwargs in registrations(alone, "register_methods"):
        add_method(trial, plugin, *args, **kwargs)
    for (card,), _ in registrations(alone, "register_protocols"):
        add_protocol(trial, plugin, card)
    for args, kwargs in registrations(alone, "register_metrics"):
        add_metric(trial, plugin, *args, **kwargs)
    return trial


def add_preset(
    registry: Registry, plugin: str, name: str, combinations: Any, description: str = "", method: str = ""
) -> None:
    rows = tuple(c if isinstance(c, str | Row) else dict(c) for c in combinations)
    registry.presets.add(name, Preset(name, rows, description, plugin, method), plugin)
    if any(isinstance(r, Row) and not r.method for r in rows):
        raise PluginError(f"plugin {plugin!r}: preset {name!r} has a Row naming no method (Row(size, method=...))")


def add_method(registry: Registry, plugin: str, method: Any) -> None:
    """A method, its presets (attributed to it) and its shipped weights."""
    if not isinstance(method, Method):
        raise PluginError(
            f"plugin {plugin!r} registered {method!r} as a method, but it is no i2pbench.registry.methods.Method"
        )
    try:
        method.check()
    except PluginError as exc:
        raise PluginError(f"plugin {plugin!r}: {exc}") from None
    registry.methods.add(method.name, method, plugin)
    for preset in method.presets:
        add_preset(registry, plugin, preset.name, method.combinations(preset), preset.description, method.name)
        registry.presets.add_aliases(preset.name, preset.aliases, plugin)
    for path in method.weights:
        registry.weights.add(str(path), str(path), plugin)


def add_metric(registry: Registry, plugin: str, metric: Any) -> None:
    """A plugin's metric; a name or column another metric has (a built-in's included) is refused, naming both."""
    from ..scoring.metrics import BUILTIN, check

    metric = check(metric, plugin)
    taken = {m.name: "i2pbench" for m in BUILTIN} | {m.column: "i2pbench" for m in BUILTIN if m.column}
    for name, other in registry.metrics.items():
        owner = registry.metrics.plugin(name)
        taken |= {other.name: owner} | ({other.column: owner} if other.column else {})
    for key in (metric.name, metric.column):
        if key and key in taken:
            raise PluginError(f"metric {key!r} is registered by both {taken[key]!r} and {plugin!r}")
    registry.metrics.add(metric.name, metric, plugin)


def add_protocol(registry: Registry, plugin: str, card: Any) -> None:
    """A plugin's protocol card; a name another card has (the default card's, i2pbench's own, included) is refused,
    naming both."""
    from ..scoring.cards import check

    registry.protocols.add(card.name, check(card, plugin), plugin)
