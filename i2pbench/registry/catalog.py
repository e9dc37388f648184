"""The registry: what the loaded plugins registered, one `Table` per kind (each stage kind, dataset, corruption,
preset, method, protocol card, metric and shipped checkpoint), and the plugins themselves.

Component, dataset and corruption tables may hold classes registered by import path (`lazy.LazyComponent`),
imported on first use; `register(..., aliases=("y",))` lets users type another name for the same component, while
rows, labels and cache keys always carry the registered (canonical) name. A preset is a named list of rows; a
method (`methods.Method`) adds its presets and shipped weights to the same tables, attributed to its plugin.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ..errors import PluginError
from ..scoring.cards import EDGEREGNET
from ..stages.components import STAGE_BASES, Component
from .lazy import LazyComponent, class_path, same_class
from .loading import PluginInfo
from .methods import Method, Row
from .table import NAME_CLASH, Table

if TYPE_CHECKING:  # imported to check a class: listing what was registered by path needs neither
    from ..corruptions.base import Corruption
    from ..data.base import Dataset
    from ..scoring.cards import ProtocolCard
    from ..scoring.metrics import Metric

CLASS_KINDS: tuple[str, ...] = (*STAGE_BASES, "dataset", "corruption")  # kinds whose entries are classes


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


def _never(_: Any, __: Any) -> bool:
    return False


def new_tables() -> dict[str, Table[Any]]:
    """an empty table per kind, in the order `i2pbench plugins` lists them."""
    classes: dict[str, Table[Any]] = {kind: Table(kind, same_class, NAME_CLASH) for kind in CLASS_KINDS}
    return {
        **classes,
        "preset": Table("preset", _never),
        "weights": Table("weights", lambda a, b: a == b),
        "method": Table("method", _never),
        "protocol": _protocols(),
        "metric": Table("metric", _never),
    }


def _protocols() -> Table[Any]:
    """the protocol cards' table, holding i2pbench's default card from the start (as the built-in metrics are
    i2pbench's own): a run has it even when every plugin is blocked, and the built-in plugin registering it again
    is no clash."""
    table = Table("protocol", lambda a, b: a == b, NAME_CLASH)
    table.add(EDGEREGNET.name, EDGEREGNET, "i2pbench")
    return table


class Registry:
    """Every component, dataset, preset, shipped checkpoint, corruption and method the loaded plugins registered."""

    def __init__(self, tables: dict[str, Table[Any]] | None = None, plugins: list[PluginInfo] | None = None) -> None:
        self.tables = new_tables() if tables is None else tables
        self.plugins: list[PluginInfo] = [] if plugins is None else plugins

    def copy(self) -> Registry:
        """a registry to register one plugin into: every table copied, so a refused plugin leaves this one as is."""
        return Registry({kind: table.copy() for kind, table in self.tables.items()}, self.plugins)

    @property
    def components(self) -> dict[str, Table[type[Component]]]:
        return {kind: self.tables[kind] for kind in STAGE_BASES}

    @property
    def datasets(self) -> Table[type[Dataset]]:
        return self.tables["dataset"]

    @property
    def corruptions(self) -> Table[type[Corruption]]:
        return self.tables["corruption"]

    @property
    def presets(self) -> Table[Preset]:
        return self.tables["preset"]

    @property
    def methods(self) -> Table[Method]:
        return self.tables["method"]

    @property
    def protocols(self) -> Table[ProtocolCard]:
        return self.tables["protocol"]

    @property
    def metrics(self) -> Table[Metric]:
        return self.tables["metric"]

    @property
    def weights(self) -> Table[str]:
        """shipped checkpoints, by path."""
        return self.tables["weights"]

    def component(self, kind: str, name: str) -> type[Component]:
        if kind not in STAGE_BASES:
            raise PluginError(f"unknown stage kind {kind!r}; kinds are {list(STAGE_BASES)}")
        return self.resolve_class(kind, name)

    def dataset(self, name: str) -> type[Dataset]:
        return self.resolve_class("dataset", name)

    def corruption(self, name: str) -> type[Corruption]:
        return self.resolve_class("corruption", name)

    def resolve_class(self, kind: str, name: str) -> Any:
        """The class registered as `name` (or an alias), imported now if it was registered by path (and kept)."""
        table = self.tables[kind]
        name = table.lookup(name)
        entry = table[name]
        if isinstance(entry, LazyComponent):
            entry = entry.resolve()
            table.put(name, entry)
        return entry

    def preset(self, name: str) -> Preset:
        return self.presets[self.presets.lookup(name)]

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
            entry = self.presets.canonical(entry)
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
        return self.methods[self.methods.lookup(name)]

    def owner(self, kind: str, name: str) -> str:
        return self.tables[kind].plugin(name)

    def canonical(self, kind: str, name: str) -> str:
        """The registered name behind `name` (itself unless it is an alias): what rows and cache keys carry."""
        return self.tables[kind].canonical(name) if kind in self.tables else name

    def path(self, kind: str, name: str) -> str:
        """`module:Class` of a component, dataset or corruption, without importing it."""
        return class_path(self.tables[kind][self.canonical(kind, name)])
