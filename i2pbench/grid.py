"""Turning CLI options, presets and YAML grid files into the list of combinations to run."""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from .components import STAGE_ORDER
from .errors import PluginError
from .pipeline import NONE, Combination
from .plugins import Registry


def parse_conf_overrides(items: Sequence[str]) -> dict[str, dict[str, Any]]:
    """`["matcher.filter_threshold=0.2"]` -> {"matcher": {"filter_threshold": 0.2}} (values parsed as YAML)."""
    confs: dict[str, dict[str, Any]] = {}
    for item in items:
        target, sep, value = item.partition("=")
        kind, dot, key = target.partition(".")
        if not sep or not dot or kind not in STAGE_ORDER:
            raise PluginError(f"--conf {item!r}: expected KIND.KEY=VALUE with KIND one of {list(STAGE_ORDER)}")
        confs.setdefault(kind, {})[key] = yaml.safe_load(value)
    return confs


def base_combinations(registry: Registry, preset: str | None) -> list[dict[str, str]]:
    """The preset's combinations, or the "default" preset's when none is named."""
    if preset is None and "default" not in registry.presets:
        raise PluginError(
            "no 'default' preset is registered; name the stages or a --preset "
            f"(known: {', '.join(sorted(registry.presets)) or 'none'})"
        )
    return [dict(c) for c in registry.preset(preset or "default").combinations]


def expand(
    bases: Sequence[Mapping[str, str]],
    choices: Mapping[str, Sequence[str]],
    confs: Mapping[str, Mapping[str, Any]] | None = None,
) -> list[Combination]:
    """The product of the per-stage choices, applied over each base combination (duplicates dropped).

    A base may carry "confs" ({kind: {key: value}}): config a preset pins, e.g. a smaller width its weights used;
    a base conf applies only while its stage keeps the base's component, and `confs` overrides it.
    """
    kinds = [k for k in STAGE_ORDER if choices.get(k)]
    seen, out = set(), []
    for base in bases:
        base = dict(base)
        base_confs = base.pop("confs", {})
        for values in itertools.product(*(choices[k] for k in kinds)):
            names = {**base, **dict(zip(kinds, values, strict=True))}
            combination = Combination(names, _merge_confs(names, base, base_confs, confs or {}))
            if combination.key() not in seen:
                seen.add(combination.key())
                out.append(combination)
    return out


def _merge_confs(
    names: Mapping[str, str],
    base: Mapping[str, str],
    base_confs: Mapping[str, Mapping[str, Any]],
    overrides: Mapping[str, Mapping[str, Any]],
) -> dict[str, dict[str, Any]]:
    merged = {}
    for kind in STAGE_ORDER:
        if names.get(kind, NONE) == NONE:
            continue
        pinned = base_confs.get(kind, {}) if names[kind] == base.get(kind) else {}
        conf = {**pinned, **overrides.get(kind, {})}
        if conf:
            merged[kind] = conf
    return merged


def load_grid_file(path: str | Path) -> tuple[list[dict[str, str]], dict[str, list[str]]]:
    """A YAML grid: `base: {kind: name}` (optional) and `grid: {kind: [names]}`."""
    data = yaml.safe_load(Path(path).read_text()) or {}
    base = data.get("base", {})
    grid = {k: ([v] if isinstance(v, str) else list(v)) for k, v in (data.get("grid") or {}).items()}
    unknown = (set(base) | set(grid)) - set(STAGE_ORDER)
    if unknown:
        raise PluginError(f"grid file {path}: unknown stage kinds {sorted(unknown)}; kinds are {list(STAGE_ORDER)}")
    return [base], grid
