"""One generic typed table of what plugins register under names (lm-evaluation-harness's `Registry[T]`): each name
holds a value and the plugin that registered it, other names (aliases) may point at a name, a second registration of
a name is refused naming both plugins, and an unknown name suggests the closest one. The registry keeps one table per
kind (`catalog.Registry`), so copying, restoring and listing are written once, here."""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Generic, TypeVar

from ..errors import PluginError

T = TypeVar("T")

CLASH = "{what} {name!r} is registered by both {first!r} and {second!r}"
NAME_CLASH = "{what} name {name!r} is registered by both plugin {first!r} and {second!r}"


@dataclass(frozen=True)
class Entry(Generic[T]):
    """a registered value and the plugin that registered it."""

    value: T
    plugin: str


class Table(Mapping[str, T], Generic[T]):
    """name -> value for one kind (`what`: "matcher", "preset", ...), with owners and aliases. Read as a mapping it
    holds the registered (canonical) names only. `same(a, b)`: whether a second registration is the first again
    (allowed) rather than a clash; `clash`: the message of a clash."""

    def __init__(self, what: str, same: Callable[[T, T], bool] | None = None, clash: str = CLASH) -> None:
        self.what, self.same, self.clash = what, same or (lambda a, b: a is b), clash
        self.entries: dict[str, Entry[T]] = {}
        self.aliases: dict[str, Entry[str]] = {}  # alias -> (the name it stands for, the plugin that gave it)

    def __getitem__(self, name: str) -> T:
        return self.entries[name].value

    def __iter__(self) -> Iterator[str]:
        return iter(self.entries)

    def __len__(self) -> int:
        return len(self.entries)

    def copy(self) -> Table[T]:
        """a table to register one plugin into: a refused plugin leaves this one untouched."""
        twin = Table(self.what, self.same, self.clash)
        twin.entries, twin.aliases = dict(self.entries), dict(self.aliases)
        return twin

    def plugin(self, name: str) -> str:
        """the plugin that registered `name` (an alias's name)."""
        return self.entries[self.canonical(name)].plugin

    def add(self, name: str, value: T, plugin: str) -> None:
        if name in self.entries and not self.same(self.entries[name].value, value):
            message = self.clash.format(what=self.what, name=name, first=self.entries[name].plugin, second=plugin)
            raise PluginError(message)
        self.entries[name] = Entry(value, plugin)

    def put(self, name: str, value: T) -> None:
        """replace the value of a registered name, keeping its plugin (a class imported on first use)."""
        self.entries[name] = Entry(value, self.entries[name].plugin)

    def add_aliases(self, name: str, aliases: str | tuple[str, ...], plugin: str) -> None:
        """Other names for `name`; one that is already a name or another's alias is refused, as is a new name that
        is already an alias."""
        for alias in (aliases,) if isinstance(aliases, str) else aliases:
            if not (isinstance(alias, str) and alias) or alias == name:
                raise PluginError(
                    f"plugin {plugin!r} gave {self.what} {name!r} the alias {alias!r}, which is no other name"
                )
            holder = self.entries[alias].plugin if alias in self.entries else ""
            holder = holder or (self.aliases[alias].plugin if alias in self.aliases else "")
            if holder and (alias not in self.aliases or self.aliases[alias].value != name):
                raise PluginError(
                    f"{self.what} alias {alias!r} of {name!r} (plugin {plugin!r}) is a name of plugin {holder!r}"
                )
            self.aliases.setdefault(alias, Entry(name, plugin))
        if name in self.aliases:
            holder = self.aliases[name].plugin
            raise PluginError(f"{self.what} name {name!r} of plugin {plugin!r} is an alias registered by {holder!r}")

    def canonical(self, name: str) -> str:
        """the registered name behind `name` (itself unless it is an alias): what rows and cache keys carry."""
        return self.aliases[name].value if name in self.aliases else name

    def lookup(self, name: str) -> str:
        """The canonical name, or an error suggesting the closest registered name or alias."""
        name = self.canonical(name)
        if name in self.entries:
            return name
        known = [*self.entries, *self.aliases]
        close = difflib.get_close_matches(name, known, n=1, cutoff=0.5)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise PluginError(f"unknown {self.what} {name!r}{hint} (known: {', '.join(sorted(known)) or 'none'})")

    def owners(self) -> dict[str, str]:
        """name -> the plugin that registered it, in the order registered."""
        return {name: entry.plugin for name, entry in self.entries.items()}

    def names_of(self, plugin: str) -> list[str]:
        """the names `plugin` registered, in the order it registered them."""
        return [name for name, entry in self.entries.items() if entry.plugin == plugin]

    def aliases_of(self, plugin: str) -> dict[str, list[str]]:
        """the aliases `plugin` gave, by the name they stand for, each list sorted."""
        out: dict[str, list[str]] = {}
        for alias, entry in sorted(self.aliases.items()):
            if entry.plugin == plugin:
                out.setdefault(entry.value, []).append(alias)
        return out
