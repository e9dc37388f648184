"""Which components a plugin registers, read straight from its hooks (no entry points, no environment needed)."""

from __future__ import annotations

from ..components import Component
from ..hookspecs import STAGE_HOOKS


def registered_components(plugin: object) -> list[type[Component]]:
    """Every class the plugin's stage hooks register, in hook order, so a test can run the kit on each."""
    found: list[type[Component]] = []
    for hook in STAGE_HOOKS.values():
        impl = getattr(plugin, hook, None)
        if callable(impl):
            impl(register=found.append)
    return found
