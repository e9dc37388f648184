"""Turning CLI options, presets and YAML grid files into the list of combinations to run, and `--corruption` specs
into the protocols to run them under."""

from __future__ import annotations

import functools
import itertools
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..corruptions.base import Corruption, NotApplicable, unavailable
from ..data import yaml_input
from ..errors import PluginError
from ..registry.catalog import Registry
from ..scoring.protocol import Protocol
from ..stages.components import STAGE_BASES, STAGE_ORDER
from ..stages.config import overlay
from ..stages.pipeline import NONE, REQUIRED_STAGES, Combination

if TYPE_CHECKING:
    from ..data.base import Dataset

GRID_KEYS = ("base", "grid", "confs")
CLEAN, ALL = "clean", "all"  # --corruption words: the uncorrupted protocol, every registered corruption


OPTIONAL_STAGES = tuple(k for k in STAGE_ORDER if k not in REQUIRED_STAGES)


def parse_conf_overrides(items: Sequence[str]) -> dict[str, dict[str, Any]]:
    """`["matcher.filter_threshold=0.2", "encoder3d.sa1.radius=0.2"]` -> {"matcher": {"filter_threshold": 0.2},
    "encoder3d": {"sa1": {"radius": 0.2}}}: values parsed as YAML, dots after the kind nest."""
    confs: dict[str, dict[str, Any]] = {}
    for item in items:
        target, sep, value = item.partition("=")
        kind, *path = target.split(".")
        if not sep or not all(path) or not path or kind not in STAGE_ORDER:
            raise PluginError(f"--conf {item!r}: expected KIND.KEY=VALUE with KIND one of {list(STAGE_ORDER)}")
        setting: Any = yaml_input.load(value)
        for key in reversed(path):
            setting = {key: setting}
        confs[kind] = overlay(confs.get(kind, {}), setting)
    return confs


def base_combinations(registry: Registry, preset: str | None, stages_named: bool = False) -> list[dict[str, str]]:
    """The preset's combinations (several presets comma-separated: their union), or the "default" preset's.

    With no preset and no "default" registered, a command that names its stages (`stages_named`) starts from an
    empty base, so `--extractor lsd --extractor3d depth ...` works before any default pipeline exists.
    """
    if preset is None and registry.presets.canonical("default") not in registry.presets:  # "default" may be an alias
        if stages_named:
            return [{}]
        raise PluginError(
            "no 'default' preset is registered; name the stages or a --preset "
            f"(known: {', '.join(sorted(registry.presets)) or 'none'})"
        )
    combinations: list[dict[str, str]] = []
    for name in (preset or "default").split(","):  # "a,b": the union of presets, each combination once
        for combination in registry.preset_rows(name.strip()):
            if combination not in combinations:
                combinations.append(combination)
    return combinations


def expand(
    bases: Sequence[Mapping[str, str]],
    choices: Mapping[str, Sequence[str]],
    confs: Mapping[str, Mapping[str, Any]] | None = None,
    registry: Registry | None = None,
) -> list[Combination]:
    """The product of the per-stage choices, applied over each base combination (duplicates dropped).

    A base may carry "confs" ({kind: {key: value}}): config a preset pins, e.g. the size a method's weights
    were trained at (i2pbench.registry.methods), and a "variant" label for them; a base conf applies only while its
    stage keeps the base's component, and `confs` overrides it. With a registry, names are canonical (an alias gives
    the same row as its name), and stages taken from the base whose outputs no later stage consumes are dropped
    (`--matcher oracle` over the default pipeline needs no encoders); stages the user named are always kept.
    """
    kinds = [k for k in STAGE_ORDER if choices.get(k)]
    choices = {k: [_canonical(registry, k, name) for name in choices[k]] for k in kinds}
    seen, out = set(), []
    for base in bases:
        base = dict(base)
        base_confs, variant = base.pop("confs", {}), base.pop("variant", "")
        base = {k: _canonical(registry, k, name) for k, name in base.items()}
        for values in itertools.product(*(choices[k] for k in kinds)):
            names = {**base, **dict(zip(kinds, values, strict=True))}
            if registry is not None:
                names = prune_unconsumed(registry, names, keep=set(kinds))
            merged = _merge_confs(names, base, base_confs, confs or {}, registry)
            pinned = any(merged.get(k, {}).items() >= dict(v).items() for k, v in base_confs.items() if v)
            shown = {k: dict(v) for k, v in (confs or {}).items() if names.get(k, NONE) != NONE}
            combination = Combination(names, merged, variant if pinned else "", shown)
            if combination.key() not in seen:
                seen.add(combination.key())
                out.append(combination)
    return out


def _canonical(registry: Registry | None, kind: str, name: str) -> str:
    """The registered name behind an alias (unchanged without a registry, or for a kind it does not know)."""
    return name if registry is None or kind not in STAGE_ORDER else registry.canonical(kind, name)


def prune_unconsumed(registry: Registry, names: Mapping[str, str], keep: set[str]) -> dict[str, str]:
    """Drop optional stages (encoders, exchanger) whose outputs nothing downstream consumes, unless in `keep`.

    What a stage hands on is fixed by its kind (`calling.StageInputs.after`: an encoder's output is descriptors), so
    it is judged by its kind's `provides` and imported only when kept: `--matcher oracle` over the default preset
    imports none of the learned stages it drops, nor torch."""
    names, needed = dict(names), set()
    for kind in reversed(STAGE_ORDER):
        name = names.get(kind, NONE)
        if name == NONE:
            continue
        if kind in OPTIONAL_STAGES and kind not in keep and not STAGE_BASES[kind].provides & needed:
            names[kind] = NONE
            continue
        needed |= registry.component(kind, name).consumes
    return names


def _merge_confs(
    names: Mapping[str, str],
    base: Mapping[str, str],
    base_confs: Mapping[str, Mapping[str, Any]],
    overrides: Mapping[str, Mapping[str, Any]],
    registry: Registry | None = None,
) -> dict[str, dict[str, Any]]:
    """Pinned confs apply to stages that kept the base's component; a non-learned stage's pins (e.g. an extractor's
    keypoint cap a method's size sets) serve the base's learned stages, so they apply only while one of those is kept
    too."""
    kept = {k for k in base_confs if names.get(k, NONE) == base.get(k) != NONE}
    if registry is not None:
        learned = {k for k in kept if registry.component(k, names[k]).learned}
        kept = kept if learned else set()
    merged = {}
    for kind in STAGE_ORDER:
        if names.get(kind, NONE) == NONE:
            continue
        conf = overlay(base_confs[kind] if kind in kept else {}, overrides.get(kind, {}))
        if conf:
            merged[kind] = conf
    return merged


@dataclass(frozen=True)
class GridFile:
    """A YAML grid: `base: {kind: name}`, `grid: {kind: [names]}` (their product) and `confs: {kind: {key: value}}`."""

    base: dict[str, str] = field(default_factory=dict)
    grid: dict[str, list[str]] = field(default_factory=dict)
    confs: dict[str, dict[str, Any]] = field(default_factory=dict)


def load_grid_file(path: str | Path) -> GridFile:
    """Read and check a grid file; unknown keys and stage kinds are refused, naming the file."""
    data = yaml_input.load(Path(path).read_text()) or {}
    if not isinstance(data, dict) or set(data) - set(GRID_KEYS):
        found = sorted(data) if isinstance(data, dict) else type(data).__name__
        raise PluginError(f"grid file {path}: expected a mapping with keys {list(GRID_KEYS)}, found {found}")
    base = {k: _name(v) for k, v in (data.get("base") or {}).items()}
    grid = {k: [_name(n) for n in (v if isinstance(v, list) else [v])] for k, v in (data.get("grid") or {}).items()}
    confs = {k: dict(v) for k, v in (data.get("confs") or {}).items()}
    unknown = (set(base) | set(grid) | set(confs)) - set(STAGE_ORDER)
    if unknown:
        raise PluginError(f"grid file {path}: unknown stage kinds {sorted(unknown)}; kinds are {list(STAGE_ORDER)}")
    return GridFile(base, grid, confs)


def _name(value: Any) -> str:
    """YAML reads a bare `null`/`~` as None: for a stage that means "none" (skipped)."""
    return NONE if value is None else str(value)


def protocols(
    registry: Registry,
    base: Protocol,
    specs: Sequence[str],
    severities: Sequence[int] | None = None,
    dataset: Dataset | None = None,
    frame_ids: Sequence[str] | None = None,
) -> list[Protocol]:
    """The protocols `--corruption` names, in order, each once: `clean`, `NAME` (every severity, or `severities`),
    `NAME:S`, or `all` (every registered corruption that applies, as NAME).

    A corruption runs on every frame of the run or on none, so its rows cover the clean rows' frames. Given the
    `dataset` (and the `frame_ids` to run, default all), one that needs what a frame lacks is left out of `all`
    (said on stderr) and refused by name; without it, `all` leaves out every corruption with `needs` (nothing to
    check them against) and a named one stops the run at the first frame it does not apply to."""
    ids = None if dataset is None else list(frame_ids if frame_ids is not None else dataset.frame_ids())
    reason = functools.cache(lambda name: _unavailable(registry.corruption(name)(), dataset, ids))
    out: list[Protocol] = []
    for spec in specs:
        name, sep, severity = spec.partition(":")
        if name == CLEAN:
            chosen = [base]
        else:
            if name != ALL and dataset is not None and reason(name):
                raise NotApplicable(f"--corruption {spec}: {reason(name)}")
            names = _applicable(registry, reason) if name == ALL else [name]
            chosen = [p for n in names for p in _of(registry, base, n, severity if sep else None, severities)]
        out += [p for p in chosen if p not in out]
    return out


def _unavailable(corruption: Corruption, dataset: Dataset | None, frame_ids: Sequence[str] | None) -> str:
    if dataset is None or frame_ids is None:
        return f"it needs {', '.join(corruption.needs)}, with no dataset to check" if corruption.needs else ""
    return unavailable(corruption, dataset, frame_ids)


def _applicable(registry: Registry, reason: Callable[[str], str]) -> list[str]:
    """Every registered corruption that applies, by name; each left out is said on stderr, with why."""
    names = []
    for name in sorted(registry.corruptions):
        if reason(name):
            print(f"i2pbench: note: corruption {name!r} left out of 'all': {reason(name)}", file=sys.stderr)
        else:
            names.append(name)
    return names


def _of(
    registry: Registry, base: Protocol, name: str, severity: str | None, severities: Sequence[int] | None
) -> list[Protocol]:
    corruption = registry.corruption(name)()
    if severity is not None:
        if not severity.isdigit():
            raise PluginError(
                f"--corruption {name}:{severity}: the severity must be a number 1..{len(corruption.levels)}"
            )
        chosen: Sequence[int] = [int(severity)]
    else:
        chosen = [s for s in corruption.severities if severities is None or s in severities]
    return [base.corrupted(corruption, s) for s in chosen]
