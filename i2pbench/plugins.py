"""Loading plugins from the `i2pbench` entry-point group and the name -> component registry built from them.

Environment variables (as llm's LLM_LOAD_PLUGINS):
- I2PBENCH_LOAD_PLUGINS: comma-separated entry-point names; when set, only these are loaded ("" loads none).
- I2PBENCH_BLOCK_PLUGINS: comma-separated entry-point names never to load.

A plugin that fails to import, whose hooks raise, or whose registrations are refused (a name another plugin took,
a class that is no component) is skipped whole, with a warning, and listed as failed: one broken third-party
package must not take every command down with it, `i2pbench plugins` included. The built-in plugins register first,
so a clash with one of them skips the newcomer and keeps the built-in; between two others the one loaded later
(entry points in name order) is skipped. `strict=True` raises instead, for tests and plugin authors.

A component or dataset may be registered by import path, `register("package.module:Class", name="x")`: the registry
keeps its name and imports the class on first use, so listing plugins, or running other stages, never imports what
it needs (a learned stage's torch). A path that cannot be imported is an error when the component is used
(`strict=True` imports every path while registering). `register(..., aliases=("y",))` lets users type another name
for the same component; rows, labels and cache keys always carry the registered (canonical) name.

A method (`register_methods`, i2pbench.methods.Method) adds its presets and shipped weights to the same tables,
attributed to its plugin, and is kept whole for `i2pbench plugins`.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import pluggy

from . import hookspecs
from .components import STAGE_BASES, STAGES, Component
from .entry_points import EntryPoint, installed
from .errors import PluginError
from .methods import Method, Row

if TYPE_CHECKING:  # imported to check a class: listing what was registered by path needs neither
    from .corruptions import Corruption
    from .data.base import Dataset

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
    """A named list of rows: combinations, (a str) the name of another preset whose rows come in its place, so a
    table spanning several plugins' methods (a paper's comparison) is declared without copying their rows, or (a
    `methods.Row`) a row of a registered method, built from its declaration when the preset is expanded."""

    name: str
    combinations: tuple[dict[str, Any] | str | Row, ...]
    description: str
    plugin: str
    method: str = ""  # the method that declared it ("": registered by register_presets)


@dataclass(frozen=True)
class LazyComponent:
    """A component or dataset registered by import path and name, not yet imported."""

    path: str  # "package.module:Class"
    kind: str  # a stage kind, "dataset" or "corruption"
    name: str
    plugin: str

    def resolve(self) -> type:
        """Import the class and check it is what was registered: the hook's base class, and the same `name`."""
        module, _, qualname = self.path.partition(":")
        try:
            cls: Any = importlib.import_module(module)
            for attr in qualname.split("."):
                cls = getattr(cls, attr)
        except (Exception, SystemExit) as exc:  # a broken plugin fails the command that uses it, with its name
            raise PluginError(
                f"plugin {self.plugin!r} registered {self.kind} {self.name!r} as {self.path!r}, which cannot be "
                f"imported: {type(exc).__name__}: {exc}"
            ) from exc
        _check_class(cls, self.kind, self.plugin)
        if cls.name != self.name:
            raise PluginError(
                f"plugin {self.plugin!r} registered {self.path} as {self.kind} {self.name!r}, "
                f"but its name is {cls.name!r}"
            )
        return cls


Entry = tuple[Any, str]  # (class or LazyComponent, plugin)


@dataclass
class Registry:
    """Every component, dataset, preset, shipped checkpoint, corruption and method the loaded plugins registered."""

    components: dict[str, dict[str, Entry]] = field(default_factory=lambda: {kind: {} for kind in STAGE_BASES})
    datasets: dict[str, Entry] = field(default_factory=dict)
    presets: dict[str, Preset] = field(default_factory=dict)
    weights: list[tuple[str, str]] = field(default_factory=list)  # (path, plugin)
    plugins: list[PluginInfo] = field(default_factory=list)
    corruptions: dict[str, Entry] = field(default_factory=dict)
    aliases: dict[str, dict[str, Entry]] = field(default_factory=dict)  # table kind -> alias -> (name, plugin)
    methods: dict[str, Entry] = field(default_factory=dict)  # name -> (Method, plugin)
    protocols: dict[str, Entry] = field(default_factory=dict)  # name -> (scoring.cards.ProtocolCard, plugin)
    metrics: dict[str, Entry] = field(default_factory=dict)  # name -> (metric_registry.Metric, plugin)

    def component(self, kind: str, name: str) -> type[Component]:
        if kind not in self.components:
            raise PluginError(f"unknown stage kind {kind!r}; kinds are {list(self.components)}")
        return _resolved(self.components[kind], self._name(kind, name))

    def dataset(self, name: str) -> type[Dataset]:
        return _resolved(self.datasets, self._name("dataset", name))

    def corruption(self, name: str) -> type[Corruption]:
        return _resolved(self.corruptions, self._name("corruption", name))

    def preset(self, name: str) -> Preset:
        return self.presets[_lookup(self.presets, name, "preset")]

    def preset_rows(self, name: str, _within: tuple[str, ...] = ()) -> list[dict[str, Any]]:
        """The preset's combinations, included presets and method rows expanded in place (resolved now, so plugins
        may register in any order); an included preset no loaded plugin registers, or a cycle, is an error naming
        both. A row of a method no loaded plugin registers is left out, and a preset left with no row is an error
        naming the methods it needs."""
        preset = self.preset(name)
        rows: list[dict[str, Any]] = []
        for entry in preset.combinations:
            if not isinstance(entry, str):
                row = self.row(entry)
                rows += [row] if row is not None else []
                continue
            if entry in (*_within, preset.name):
                raise PluginError(f"preset {preset.name!r} (plugin {preset.plugin!r}) includes itself via {entry!r}")
            if entry not in self.presets:
                raise PluginError(
                    f"preset {preset.name!r} (plugin {preset.plugin!r}) includes preset {entry!r}, which no loaded "
                    "plugin registers: install the plugin that declares it"
                )
            rows.extend(self.preset_rows(entry, (*_within, preset.name)))
        if not rows and preset.combinations:
            needed = sorted({e.method for e in preset.combinations if isinstance(e, Row)})
            raise PluginError(f"preset {preset.name!r} (plugin {preset.plugin!r}) is built on method(s) "
                              f"{', '.join(needed)}, which no loaded plugin registers: install the plugin that "
                              "declares it")  # fmt: skip
        return rows

    def row(self, entry: Mapping[str, Any] | Row) -> dict[str, Any] | None:
        """A preset entry's combination: a plain one copied, a method's `Row` built from the method (None when no
        loaded plugin registers that method)."""
        if not isinstance(entry, Row):
            return dict(entry)
        return self.method(entry.method).resolve(entry) if entry.method in self.methods else None

    def method(self, name: str) -> Method:
        return self.methods[_lookup(self.methods, name, "method")][0]

    def owner(self, kind: str, name: str) -> str:
        return self.components[kind][self.canonical(kind, name)][1]

    def canonical(self, kind: str, name: str) -> str:
        """The registered name behind `name` (itself unless it is an alias): what rows and cache keys carry."""
        return self.aliases.get(kind, {}).get(name, (name, ""))[0]

    def path(self, kind: str, name: str) -> str:
        """`module:Class` of a component, dataset or corruption, without importing it."""
        entry = self._table(kind)[self.canonical(kind, name)][0]
        return entry.path if isinstance(entry, LazyComponent) else f"{entry.__module__}:{entry.__qualname__}"

    def _table(self, kind: str) -> dict[str, Entry]:
        other = {"dataset": self.datasets, "corruption": self.corruptions}
        return other[kind] if kind in other else self.components[kind]

    def _name(self, kind: str, name: str) -> str:
        """The canonical name, or an error suggesting the closest registered name or alias."""
        table, aliases = self._table(kind), self.aliases.get(kind, {})
        name = self.canonical(kind, name)
        return name if name in table else _lookup({**table, **aliases}, name, kind)


def _resolved(table: dict[str, Entry], name: str) -> Any:
    """The class registered as `name`, imported now if it was registered by path (and kept for the next call)."""
    entry, plugin = table[name]
    if isinstance(entry, LazyComponent):
        entry = entry.resolve()
        table[name] = (entry, plugin)
    return entry


def _lookup(table: dict[str, Any], name: str, what: str) -> str:
    if name in table:
        return name
    import difflib  # only to suggest a name: listing plugins never needs it

    close = difflib.get_close_matches(name, list(table), n=1, cutoff=0.5)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    raise PluginError(f"unknown {what} {name!r}{hint} (known: {', '.join(sorted(table)) or 'none'})")


def _env_names(var: str) -> set[str] | None:
    value = os.environ.get(var)
    if value is None:
        return None
    return {part.strip() for part in value.split(",") if part.strip()}


def _selected_entry_points() -> list[EntryPoint]:
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
    for ep in _selected_entry_points():
        try:
            plugin = ep.load()
            pm.register(plugin, name=ep.name)
        except (Exception, SystemExit) as exc:  # a broken third-party plugin must not take the tool down with it
            error = f"failed to import (entry point {ep.name} = {ep.value}): {type(exc).__name__}: {exc}"
            if strict:
                raise PluginError(f"plugin {ep.name!r} {error}") from exc
            _warn(ep.name, error)
            infos.append(PluginInfo(ep.name, ep.version, ep.distribution, (), error))
            continue
        infos.append(PluginInfo(ep.name, ep.version, ep.distribution, _hooks_of(plugin)))
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


def plugin_alone(plugin: object, name: str) -> pluggy.PluginManager:
    """A plugin manager holding only `plugin`: its hooks, called through pluggy, call that plugin alone, so what they
    register is attributed to it. (pluggy's subset_hook_caller would do on the shared manager, but it hashes every
    other plugin, and a plugin object need not be hashable.)"""
    pm = pluggy.PluginManager(ENTRY_POINT_GROUP)
    pm.add_hookspecs(hookspecs)
    pm.register(plugin, name=name)
    return pm


def _collect(alone: pluggy.PluginManager, hook_name: str) -> list[tuple[tuple[Any, ...], dict[str, Any]]]:
    """What the one plugin `alone` holds registers from one hook: each `register(...)` call's arguments."""
    out: list[tuple[tuple[Any, ...], dict[str, Any]]] = []
    getattr(alone.hook, hook_name)(register=lambda *args, **kwargs: out.append((args, kwargs)))
    return out


def _check_class(cls: Any, kind: str, plugin: str) -> None:
    from .corruptions import Corruption, check_class
    from .data.base import Dataset

    base = {"dataset": Dataset, "corruption": Corruption}.get(kind) or STAGE_BASES[kind]
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise PluginError(f"plugin {plugin!r} registered {cls!r} as a {kind}, but it does not subclass {base.__name__}")
    if not cls.name:
        raise PluginError(f"plugin {plugin!r} registered {cls.__name__} without a `name`")
    if kind == "corruption":
        check_class(cls, plugin)


def _entry(kind: str, plugin: str, target: Any, name: str | None = None) -> tuple[str, Any]:
    """`register(cls)` or `register("package.module:Class", name=...)` -> (name, class or LazyComponent)."""
    if not isinstance(target, str):
        _check_class(target, kind, plugin)
        if name is not None and name != target.name:
            raise PluginError(
                f"plugin {plugin!r} registered {target.__name__} as {name!r}, but its name is {target.name!r}"
            )
        return target.name, target
    module, _, qualname = target.partition(":")
    if not (module and qualname and isinstance(name, str) and name):
        raise PluginError(
            f"plugin {plugin!r} registered {kind} {target!r}: a path needs the form 'package.module:Class' and a name, "
            "register('package.module:Class', name='my-name')"
        )
    return name, LazyComponent(target, kind, name, plugin)


def _same(a: Any, b: Any) -> bool:
    """Whether two registrations are one class (registered twice, or once eagerly and once by its path)."""
    if a is b:
        return True
    paths = [x.path if isinstance(x, LazyComponent) else f"{x.__module__}:{x.__qualname__}" for x in (a, b)]
    return (isinstance(a, LazyComponent) or isinstance(b, LazyComponent)) and paths[0] == paths[1]


def _add(table: dict[str, Entry], what: str, name: str, entry: Any, plugin: str) -> None:
    if name in table and not _same(table[name][0], entry):
        raise PluginError(f"{what} name {name!r} is registered by both plugin {table[name][1]!r} and {plugin!r}")
    table[name] = (entry, plugin)


def _add_aliases(registry: Registry, kind: str, name: str, aliases: Any, plugin: str) -> None:
    """Other names for `name`; one that is already a name or another component's alias is refused, as is a new
    name that is already an alias."""
    table, known = registry._table(kind), registry.aliases.setdefault(kind, {})
    for alias in (aliases,) if isinstance(aliases, str) else aliases:
        if not (isinstance(alias, str) and alias) or alias == name:
            raise PluginError(f"plugin {plugin!r} gave {kind} {name!r} the alias {alias!r}, which is no other name")
        holder = table[alias][1] if alias in table else known[alias][1] if alias in known else ""
        if holder and known.get(alias, ("",))[0] != name:
            raise PluginError(f"{kind} alias {alias!r} of {name!r} (plugin {plugin!r}) is a name of plugin {holder!r}")
        known.setdefault(alias, (name, plugin))
    if name in known:
        raise PluginError(f"{kind} name {name!r} of plugin {plugin!r} is an alias registered by {known[name][1]!r}")


def _add_preset(
    registry: Registry, plugin: str, name: str, combinations: Any, description: str = "", method: str = ""
) -> None:
    if name in registry.presets:
        raise PluginError(f"preset {name!r} is registered by both {registry.presets[name].plugin!r} and {plugin!r}")
    rows = tuple(c if isinstance(c, str | Row) else dict(c) for c in combinations)
    if any(isinstance(r, Row) and not r.method for r in rows):
        raise PluginError(f"plugin {plugin!r}: preset {name!r} has a Row naming no method (Row(size, method=...))")
    registry.presets[name] = Preset(name, rows, description, plugin, method)


def _add_method(registry: Registry, plugin: str, method: Any) -> None:
    """A method, its presets (attributed to it) and its shipped weights."""
    if not isinstance(method, Method):
        raise PluginError(f"plugin {plugin!r} registered {method!r} as a method, but it is no i2pbench.methods.Method")
    try:
        method.check()
    except PluginError as exc:
        raise PluginError(f"plugin {plugin!r}: {exc}") from None
    if method.name in registry.methods:
        raise PluginError(f"method {method.name!r} is registered by both {registry.methods[method.name][1]!r} and "
                          f"{plugin!r}")  # fmt: skip
    registry.methods[method.name] = (method, plugin)
    for preset in method.presets:
        _add_preset(registry, plugin, preset.name, method.combinations(preset), preset.description, method.name)
    registry.weights += [(str(path), plugin) for path in method.weights]


def _add_metric(registry: Registry, plugin: str, metric: Any) -> None:
    """A plugin's metric; a name or column another metric has (a built-in's included) is refused, naming both."""
    from .metrics.registry import BUILTIN, check

    metric = check(metric, plugin)
    taken = {m.name: "i2pbench" for m in BUILTIN} | {m.column: "i2pbench" for m in BUILTIN if m.column}
    for other, owner in registry.metrics.values():
        taken |= {other.name: owner} | ({other.column: owner} if other.column else {})
    for key in (metric.name, metric.column):
        if key and key in taken:
            raise PluginError(f"metric {key!r} is registered by both {taken[key]!r} and {plugin!r}")
    registry.metrics[metric.name] = (metric, plugin)


def _add_protocol(registry: Registry, plugin: str, card: Any) -> None:
    """A plugin's protocol card; a name another plugin (or the default card) has is refused, naming both."""
    from .scoring.cards import EDGEREGNET, check

    card = check(card, plugin)
    if card.name == EDGEREGNET.name and card != EDGEREGNET:
        raise PluginError(f"protocol {card.name!r} is i2pbench's default card; plugin {plugin!r} cannot replace it")
    if card.name in registry.protocols and registry.protocols[card.name][0] is not card:
        raise PluginError(f"protocol name {card.name!r} is registered by both plugin "
                          f"{registry.protocols[card.name][1]!r} and {plugin!r}")  # fmt: skip
    registry.protocols[card.name] = (card, plugin)


def build_registry(extra_plugins: tuple[object, ...] = (), strict: bool = False) -> Registry:
    """The registry of the selected entry-point plugins plus `extra_plugins`, built-ins first; a plugin that fails
    is skipped whole and listed with its error (`strict`: PluginError)."""
    pm, infos = make_plugin_manager(extra_plugins, strict)
    registry = Registry()
    for info in sorted(infos, key=lambda i: i.distribution != BUILTIN_DISTRIBUTION):
        if not info.failed:
            try:
                _register(registry, pm, info.name, strict)
            except (Exception, SystemExit) as exc:
                if strict:
                    raise
                error = str(exc) if isinstance(exc, PluginError) else f"raised {type(exc).__name__}: {exc}"
                _warn(info.name, f"could not register: {error}")
                info = replace(info, error=error)
        registry.plugins.append(info)
    return registry


def _copy(registry: Registry) -> Registry:
    """A registry to register one plugin into: tables copied, so a refused plugin leaves the original untouched."""
    return replace(
        registry,
        components={kind: dict(table) for kind, table in registry.components.items()},
        datasets=dict(registry.datasets),
        presets=dict(registry.presets),
        weights=list(registry.weights),
        corruptions=dict(registry.corruptions),
        aliases={kind: dict(table) for kind, table in registry.aliases.items()},
        methods=dict(registry.methods),
        protocols=dict(registry.protocols),
        metrics=dict(registry.metrics),
    )


def _register(registry: Registry, pm: pluggy.PluginManager, plugin: str, strict: bool = False) -> None:
    """Add everything one plugin registers, or (when any of it is refused) nothing at all; `strict` imports what
    was registered by path, so a wrong path fails here."""
    trial, alone = _copy(registry), plugin_alone(pm.get_plugin(plugin), plugin)
    hooks = {kind: spec.hook for kind, spec in STAGES.items()}
    hooks |= {"dataset": "register_datasets", "corruption": "register_corruptions"}
    for kind, hook in hooks.items():
        for args, kwargs in _collect(alone, hook):
            aliases = kwargs.pop("aliases", ())
            name, entry = _entry(kind, plugin, *args, **kwargs)
            _add(trial._table(kind), kind, name, entry, plugin)
            _add_aliases(trial, kind, name, aliases, plugin)
            if strict and isinstance(entry, LazyComponent):
                _resolved(trial._table(kind), name)
    for args, kwargs in _collect(alone, "register_presets"):
        _add_preset(trial, plugin, *args, **kwargs)
    for args, kwargs in _collect(alone, "register_methods"):
        _add_method(trial, plugin, *args, **kwargs)
    for (card,), _ in _collect(alone, "register_protocols"):
        _add_protocol(trial, plugin, card)
    for args, kwargs in _collect(alone, "register_metrics"):
        _add_metric(trial, plugin, *args, **kwargs)
    for table in fields(Registry):
        if table.name != "plugins":
            setattr(registry, table.name, getattr(trial, table.name))


@lru_cache(maxsize=1)
def default_registry() -> Registry:
    """The registry of the installed plugins, built once per process."""
    return build_registry()


def components_of(registry: Registry, plugin: str) -> dict[str, list[str]]:
    """What one plugin registered, by kind (for `i2pbench plugins`)."""
    out: dict[str, list[str]] = {}
    for kind in [*registry.components, "dataset", "corruption"]:
        names = sorted(n for n, (_, p) in registry._table(kind).items() if p == plugin)
        if names:
            out[kind] = names
    presets = sorted(n for n, p in registry.presets.items() if p.plugin == plugin)
    if presets:
        out["preset"] = presets
    weights = [path for path, p in registry.weights if p == plugin]
    if weights:
        out["weights"] = [os.path.basename(w) for w in weights]
    methods = sorted(n for n, (_, p) in registry.methods.items() if p == plugin)
    if methods:
        out["method"] = methods
    protocols = [n for n, (_, p) in registry.protocols.items() if p == plugin]
    if protocols:
        out["protocol"] = protocols
    metrics = sorted(n for n, (_, p) in registry.metrics.items() if p == plugin)
    if metrics:
        out["metric"] = metrics
    return out


def paths_of(registry: Registry, plugin: str) -> dict[str, dict[str, str]]:
    """Each of the plugin's components, datasets and corruptions by kind: name -> `module:Class` (nothing imported),
    one hop from a name typed on the command line to its code."""
    out: dict[str, dict[str, str]] = {}
    for kind, names in components_of(registry, plugin).items():
        if kind in registry.components or kind in ("dataset", "corruption"):
            out[kind] = {name: registry.path(kind, name) for name in names}
    return out


def aliases_of(registry: Registry, plugin: str) -> dict[str, dict[str, list[str]]]:
    """The other names of the plugin's components, by kind: name -> [aliases]."""
    out: dict[str, dict[str, list[str]]] = {}
    for kind, table in registry.aliases.items():
        for alias, (name, owner) in sorted(table.items()):
            if owner == plugin:
                out.setdefault(kind, {}).setdefault(name, []).append(alias)
    return out


def methods_of(registry: Registry, plugin: str) -> list[Method]:
    return [m for m, p in registry.methods.values() if p == plugin]
