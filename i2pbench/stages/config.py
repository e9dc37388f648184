"""A component's configuration, checked: user config merged over its `default_conf` at every depth, a key the
defaults lack refused with the closest valid one, a value of another kind than its default refused, and a pixel
length (match radius, reprojection bound) required to be a finite positive number."""

from __future__ import annotations

import copy
import difflib
import math
from collections.abc import Mapping
from typing import Any

from ..errors import PluginError


class ConfigError(PluginError, ValueError):
    """A component was given a configuration it does not understand."""


def merge_conf(defaults: Mapping[str, Any], overrides: Mapping[str, Any] | None, owner: str) -> dict[str, Any]:
    """`overrides` merged over a copy of `defaults` at every depth: a mapping given for a mapping default changes
    only the keys it names (`{"sa1": {"radius": 0.2}}` keeps sa1's other keys). A key the defaults lack, at any
    depth, is a ConfigError naming its dotted path and the closest valid one; an empty mapping default (nothing to
    check against) takes a mapping whole."""
    return _merged(defaults, overrides or {}, owner, "")


def _merged(defaults: Mapping[str, Any], overrides: Mapping[str, Any], owner: str, path: str) -> dict[str, Any]:
    conf = copy.deepcopy(dict(defaults))
    for key, value in overrides.items():
        where = f"{path}{key}"
        if key not in conf:
            raise ConfigError(_unknown_key(owner, path, str(key), conf))
        check_kind(owner, where, conf[key], value)
        nested = isinstance(conf[key], Mapping) and bool(conf[key]) and isinstance(value, Mapping)
        conf[key] = _merged(conf[key], value, owner, f"{where}.") if nested else value
    return conf


def overlay(base: Mapping[str, Any], more: Mapping[str, Any]) -> dict[str, Any]:
    """`more` over `base`, nested mappings merged rather than replaced and nothing checked: overrides from several
    places (a preset's pins, a grid file, --conf) combined before `merge_conf` checks them against the defaults."""
    out = dict(base)
    for key, value in more.items():
        both = isinstance(out.get(key), Mapping) and isinstance(value, Mapping)
        out[key] = overlay(out[key], value) if both else value
    return out


def _unknown_key(owner: str, path: str, key: str, known: Mapping[str, Any]) -> str:
    names = [str(k) for k in known]
    close = difflib.get_close_matches(key, names, n=1, cutoff=0.5)
    hint = f"; did you mean {path + close[0]!r}?" if close else ""
    where = f" under {path[:-1]!r}" if path else ""
    return f"{owner}: unknown config key {path + key!r}{hint} (known keys{where}: {', '.join(names)})"


LENGTHS = ("radius_px", "reproj")  # keys that are pixel lengths (match radii, reprojection error bounds): above 0


def _kind(value: Any) -> str | None:
    """the kind of value a config key holds, for the check below; None: any value goes (a None default, or None)."""
    if value is None:
        return None
    if isinstance(value, bool):
        return "true or false"
    if isinstance(value, int | float):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list | tuple):
        return "a list"
    return "a mapping" if isinstance(value, Mapping) else None


def check_kind(owner: str, key: str, default: Any, value: Any) -> None:
    """Refuse a value of another kind than its default (a string where a list goes would be read as its
    characters). A None default or value, and ints for floats, go through."""
    want, got = _kind(default), _kind(value)
    if want is not None and got is not None and want != got:
        raise ConfigError(f"{owner}: config {key} = {value!r} is {got}, but {key} takes {want} (default {default!r})")
    if got != "a number":
        return
    if math.isnan(value):
        raise ConfigError(f"{owner}: config {key} = nan is no number to compare with; give a number")
    lengths = any(word in key for word in LENGTHS) and isinstance(default, int | float) and default > 0
    if lengths and not (math.isfinite(value) and value > 0):  # a radius of 0 or -3 px matches nothing, silently
        raise ConfigError(f"{owner}: config {key} = {value!r}: a radius or error bound is a finite positive number")
