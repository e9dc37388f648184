"""A method: learned stages trained together, declared once (DESIGN principle 8).

A `Method` names the component at every stage kind, the sizes its learned stages come in (named sets of stage
configs, e.g. the paper's and a CPU-trainable one), its presets (rows built from a size, with stages swapped for
ablations) and the checkpoints it ships. A plugin registers it from `register_methods`; the registry turns it into
presets and shipped weights, so a second learned method needs no glue of its own: `--preset`, the variant label of
its rows, `--weights auto` and the checkpoint check all read what is declared here.

A preset row is the same plain mapping `register_presets` takes: stage names, plus "confs" (the configs the row
pins) and "variant" (the size's label); `register_presets` takes a `Row` naming a registered method too. Nothing here
imports a component, so `i2pbench plugins` stays light.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import PluginError
from ..stages.components import LEARNABLE_KINDS, STAGE_ORDER

Confs = Mapping[str, Mapping[str, Any]]  # stage kind -> config overrides


@dataclass(frozen=True)
class Size:
    """One size of a method: configs for its own components, and pins that serve them.

    `confs` apply where a row keeps the size's component at that kind (a swapped stage runs its own defaults);
    `pins` apply to whatever component a row puts at that kind (e.g. the keypoint count the learned stages were
    sized for, given to any extractor of an ablation row). `stages` names components this size runs instead of the
    method's (a size whose layers differ in kind, not only in width: e.g. the authors' own network). `variant` is
    the label rows at this size carry (None: the size's name; "" for the reference size, whose rows carry none).
    """

    name: str
    confs: Confs = field(default_factory=dict)
    pins: Confs = field(default_factory=dict)
    variant: str | None = None
    description: str = ""
    stages: Mapping[str, str] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return self.name if self.variant is None else self.variant


@dataclass(frozen=True)
class Row:
    """A preset row: a method at one of its sizes, with some stages swapped (`{"exchanger": "none"}`), `confs` for
    the row's stages (replacing the size's at those kinds: a swapped-in component's own) and its own `variant` label
    (None: the size's). In a method's presets the method is the declaring one; in `register_presets` a row names
    the registered `method` it is built on, resolved when the preset is expanded, so a plugin builds rows on
    another plugin's method without importing it."""

    size: str
    swaps: Mapping[str, str] = field(default_factory=dict)
    method: str = ""
    confs: Confs = field(default_factory=dict)
    variant: str | None = None


@dataclass(frozen=True)
class MethodPreset:
    """A named list of rows: `Row`s of the method, or plain combinations (e.g. a non-learned reference row).
    `aliases`: other names `--preset` takes for it (a former name users may have typed)."""

    name: str
    rows: tuple[Row | Mapping[str, Any], ...]
    description: str = ""
    aliases: tuple[str, ...] = ()


@dataclass(frozen=True)
class Method:
    """A method's stages, sizes, presets and shipped checkpoints; see the module docstring."""

    name: str
    stages: Mapping[str, str]  # stage kind -> component name, for every kind the method runs
    sizes: tuple[Size, ...]
    presets: tuple[MethodPreset, ...] = ()
    weights: tuple[str | Path, ...] = ()  # checkpoint files, offered to `--weights auto`
    description: str = ""
    # `i2pbench weights import NAME FILE`: NAME -> "package.module:function", a function of the file's path returning
    # i2pbench.weights.checkpoints.ImportedWeights (another code base's checkpoint mapped onto one of the sizes)
    importers: Mapping[str, str] = field(default_factory=dict)
    title: str = ""  # how boards name the method (their `method` column), e.g. "DeepI2P"; default: `name`

    @property
    def label(self) -> str:
        return self.title or self.name

    def components(self, kind: str) -> set[str]:
        """The components this method runs at `kind`, at any of its sizes."""
        return {stages[kind] for stages in (self.stages, *(s.stages for s in self.sizes)) if kind in stages}

    def size(self, name: str) -> Size:
        for size in self.sizes:
            if size.name == name:
                return size
        known = ", ".join(s.name for s in self.sizes)
        raise PluginError(f"method {self.name!r} has no size {name!r} (sizes: {known})")

    def row(self, size: str, **swaps: str) -> dict[str, Any]:
        """The combination of a preset row: the method's stages at `size`, `swaps` replacing some of them."""
        unknown = set(swaps) - set(STAGE_ORDER)
        if unknown:
            raise PluginError(f"method {self.name!r}: a row swaps unknown stage kinds {sorted(unknown)}")
        chosen = self.size(size)
        mine = {**self.stages, **chosen.stages}
        names = {**mine, **swaps}
        own = {kind: conf for kind, conf in chosen.confs.items() if names.get(kind) == mine[kind]}
        confs = copy.deepcopy({**own, **chosen.pins})
        return {**names, "confs": confs, "variant": chosen.label}

    def resolve(self, row: Row) -> dict[str, Any]:
        """The combination of a `Row` of this method."""
        if row.method not in ("", self.name):
            raise PluginError(f"method {self.name!r}: a row of method {row.method!r} is not one of its rows")
        if set(row.confs) - set(STAGE_ORDER):
            raise PluginError(f"method {self.name!r}: a row configures unknown stage kinds {sorted(row.confs)}")
        out = self.row(row.size, **row.swaps)
        out["confs"].update(copy.deepcopy({kind: dict(conf) for kind, conf in row.confs.items()}))
        if row.variant is not None:
            out["variant"] = row.variant
        return out

    def combinations(self, preset: MethodPreset) -> list[dict[str, Any]]:
        """The preset's rows as the combinations `register_presets` would take."""
        return [self.resolve(r) if isinstance(r, Row) else copy.deepcopy(dict(r)) for r in preset.rows]

    def check(self) -> None:
        """Refuse a declaration that cannot work, before anything runs: unknown kinds, duplicate or unknown sizes."""
        unknown = set(self.stages) - set(STAGE_ORDER)
        if not self.name or unknown:
            raise PluginError(f"method {self.name!r}: needs a name, and stage kinds among {list(STAGE_ORDER)}")
        names = [s.name for s in self.sizes]
        if not names or len(set(names)) != len(names):
            raise PluginError(f"method {self.name!r}: needs at least one size, each named once (got {names})")
        for size in self.sizes:
            stray = (
                set(size.confs) - set(self.stages)
                | set(size.pins) - set(STAGE_ORDER)
                | set(size.stages) - set(self.stages)
            )
            if stray:
                raise PluginError(f"method {self.name!r} size {size.name!r} configures kinds {sorted(stray)} it lacks")
        for preset in self.presets:
            self.combinations(preset)  # an unknown size or swapped kind is refused here

    def describe(self) -> dict[str, Any]:
        """What `i2pbench plugins --json` shows of the method."""
        return {
            "name": self.name,
            "description": self.description,
            "stages": dict(self.stages),
            "sizes": {s.name: _describe_size(s) for s in self.sizes},
            "presets": [p.name for p in self.presets],
            "preset_aliases": {p.name: list(p.aliases) for p in self.presets if p.aliases},
            "weights": [Path(w).name for w in self.weights],
            "importers": sorted(self.importers),
        }


OWN_KINDS = LEARNABLE_KINDS  # the stages a method's rows are recognised by (encoders, exchanger, matcher)


def method_of(methods: Mapping[str, Method], owner: Mapping[str, str], stages: Mapping[str, str]) -> str:
    """The `method` column of a row running `stages` (kind -> component name): the method one of whose own
    components (an encoder, the exchanger, the matcher: in that order) the row runs, so an ablation row is still its
    method's; else the plugin that registered the row's matcher (`owner`), e.g. "classic"; else ""."""
    for kind in OWN_KINDS:
        for method in methods.values():
            if stages.get(kind, "none") != "none" and stages[kind] in method.components(kind):
                return method.label
    return owner.get(stages.get("matcher", "none"), "")


def _describe_size(size: Size) -> dict[str, Any]:
    own = {"stages": dict(size.stages)} if size.stages else {}
    return {"variant": size.label, "description": size.description, **own}
