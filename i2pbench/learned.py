"""The base of stages with parameters. It subclasses torch.nn.Module, so it is kept out of i2pbench.components:
importing the stage bases (to list plugins, or to run the classic stages) must not import torch."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import torch

from .components import Component


class LearnedComponent(Component, torch.nn.Module):
    """A component with parameters; its weights live in a checkpoint shared by the pipeline's learned stages."""

    learned = True
    # config keys that only steer inference (score thresholds, filters): a checkpoint fits whatever their values, so
    # `--conf matcher.filter_threshold=0.2` can sweep them over shipped weights
    runtime_keys: ClassVar[frozenset[str]] = frozenset()

    def __init__(self, conf: Mapping[str, Any] | None = None) -> None:
        torch.nn.Module.__init__(self)
        Component.__init__(self, conf)

    __repr__ = Component.__repr__

    def compile_targets(self) -> list[torch.nn.Module]:
        """The fixed-shape submodules worth `torch.compile` (`train --compile`): none by default, since a stage's
        data-dependent loops (point sampling, say) would be unrolled or recompiled per input, not sped up."""
        return []


def width_mismatch(component: Component, upstream: Mapping[str, Component], keys: Sequence[str]) -> str | None:
    """why one of component's width keys (descriptor_dim, global_dim) disagrees with an upstream stage's, or None."""
    for kind in ("encoder2d", "encoder3d", "exchanger"):
        other = upstream.get(kind)
        theirs = getattr(other, "conf", {}) if other is not None else {}
        for key in keys:
            if key in theirs and theirs[key] != component.conf[key]:
                return f"{component.label} has {key} {component.conf[key]} but {other.label} has {key} {theirs[key]}"
    return None
