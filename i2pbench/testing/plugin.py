"""Which components a plugin registers, from its hooks called as the registry calls them (through pluggy, so only
hooks marked `@hookimpl` count), with no entry points or environment needed."""

from __future__ import annotations

import functools
from typing import Any

from ..registry.lazy import LazyComponent
from ..registry.loading import plugin_alone
from ..stages.components import STAGES, Component


def registered_components(plugin: object) -> list[type[Component]]:
    """Every class the plugin's stage hooks register, in hook order (those registered by import path imported), so a
    test can run the kit on each."""
    owner = getattr(plugin, "__name__", type(plugin).__name__)
    alone = plugin_alone(plugin, owner)  # its hooks checked against the specs, then called through pluggy
    found: list[type[Component]] = []
    for kind, spec in STAGES.items():
        getattr(alone.hook, spec.hook)(register=functools.partial(_add, found, kind, owner))
    return found


def _add(found: list[type[Component]], kind: str, owner: str, target: Any, name: str = "") -> None:
    found.append(LazyComponent(target, kind, name, owner).resolve() if isinstance(target, str) else target)
