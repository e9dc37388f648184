"""The metrics in force: i2pbench's own (`registry.BUILTIN`), then those the installed plugins register, and
what the store, boards and training validation compute from them."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
import pandas as pd

from ..protocol import Protocol
from ..registry import build
from .registry import BUILTIN, Metric, Scored


def active() -> tuple[Metric, ...]:
    """The built-in metrics, then those the installed plugins register (in plugin order)."""
    return BUILTIN + tuple(build.default_registry().metrics.values())


def record_values(scored: Scored, metrics: Iterable[Metric] | None = None) -> dict[str, float]:
    """A frame's per-frame metrics, as its record stores them."""
    return {m.name: m.frame(scored) for m in (active() if metrics is None else metrics) if m.frame is not None}


def aggregates(records: pd.DataFrame, protocol: Protocol, metrics: Iterable[Metric] | None = None) -> dict[str, Any]:
    """A row's aggregates by metric name (stds as `Metric.std`): what training validation reports."""
    out: dict[str, Any] = {}
    for metric in active() if metrics is None else metrics:
        if metric.column is None:
            continue
        values = metric.per_frame(records, protocol)
        out[metric.name] = metric.reduce(values)
        if metric.std:
            kept = pd.Series(values, dtype=float).dropna()
            out[metric.std] = float(kept.std(ddof=0)) if len(kept) else np.nan
    return out


def by_name(metrics: Iterable[Metric] | None = None) -> dict[str, Metric]:
    return {m.name: m for m in (active() if metrics is None else metrics)}
