"""YAML a user hands us (`--conf` and `--data-conf` values, grid files, split files), read without aliases.

An alias (`*name`) repeats an anchored node without copying its text, so a few hundred bytes of nested aliases (the
"billion laughs") stand for billions of values: PyYAML builds them as shared references, but anything that walks
the config afterwards (hashing it into a cache key, merging, recording it) expands them, and a 1 kB `--conf` took
0.8 GB. No option or file of ours needs an alias, so one is refused where it appears, as a YAML error: each caller
already turns those into one error line naming the option or file.
"""

from __future__ import annotations

from typing import Any

import yaml


class AliasRefused(yaml.composer.ComposerError):
    """A YAML alias in user input."""


class _NoAliasLoader(yaml.SafeLoader):
    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise AliasRefused(
                problem=f"alias *{event.anchor} refused (aliases can expand a short text without bound; write the "
                "value out)",
                problem_mark=event.start_mark,
            )
        return super().compose_node(parent, index)


def load(text: str | bytes) -> Any:
    """`yaml.safe_load`, refusing aliases (AliasRefused, a yaml.YAMLError)."""
    return yaml.load(text, Loader=_NoAliasLoader)  # noqa: S506 - a SafeLoader subclass
