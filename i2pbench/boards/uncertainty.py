"""A board's uncertainty columns, and the paired comparison of two rows read back from boards.

Each registered metric that aggregates a proportion or a mean gets `<label> 95% low` / `<label> 95% high` (Wilson,
or a seeded bootstrap: `stats`), in the aggregate's units, and `<label> 95% CI`, the two as text "[low, high]". So
that two boards (a new run and a committed baseline) can be compared frame by frame without their stores, a row
also keeps its per-frame values: `per frame <name>`, "[v1 v2 ...]" in the order of its sorted frame ids, with
`frames digest` naming that set of frames; two rows are paired only when their digests agree.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable

import numpy as np
import pandas as pd

from ..scoring.metrics import Metric
from ..scoring.protocol import Protocol
from . import stats

DIGEST = "frames digest"
VERSUS = "differs from row above"  # the Markdown board's verdict on each row against the one ranked above it
INTERVAL_AGGREGATES = ("proportion", "mean")


def low(metric: Metric) -> str:
    return f"{metric.short} 95% low"


def high(metric: Metric) -> str:
    return f"{metric.short} 95% high"


def ci(metric: Metric) -> str:
    """The text column "[low, high]" the Markdown board and the report show."""
    return f"{metric.short} 95% CI"


def per_frame(metric: Metric) -> str:
    return f"per frame {metric.name}"


def with_interval(metrics: Iterable[Metric]) -> list[Metric]:
    return [m for m in metrics if m.column is not None and m.aggregate in INTERVAL_AGGREGATES]


def interval(metric: Metric, values: np.ndarray | None) -> tuple[float, float]:
    """The 95% interval of the metric's aggregate of `values` (NaN: left out), scaled as the aggregate is."""
    if values is None:
        return math.nan, math.nan
    values = np.asarray(values, dtype=float)
    values = values[~np.isnan(values)]
    if metric.aggregate == "proportion":
        low_, high_ = stats.wilson(int(values.sum()), len(values))
    else:
        low_, high_ = stats.bootstrap_mean(values)
    return metric.scale * low_, metric.scale * high_


def cells(records: pd.DataFrame, protocol: Protocol, metrics: Iterable[Metric]) -> dict[str, object]:
    """A row's interval columns, and (when the records name their frames) its frames digest and per-frame values."""
    chosen = with_interval(metrics)
    out: dict[str, object] = {}
    for metric in chosen:
        a, b = out[low(metric)], out[high(metric)] = interval(metric, metric.per_frame(records, protocol))
        out[ci(metric)] = "-" if math.isnan(a) or math.isnan(b) else f"[{a:{metric.fmt}}, {b:{metric.fmt}}]"
    if "frame_id" not in records:
        return out
    order = np.argsort(records["frame_id"].astype(str).to_numpy(), kind="stable")
    ids = records["frame_id"].astype(str).to_numpy()[order]
    out[DIGEST] = "sha256:" + hashlib.sha256("\n".join(ids).encode()).hexdigest()[:16]  # text, never a number
    for metric in chosen:
        values = metric.per_frame(records, protocol)
        text = "" if values is None else " ".join(f"{v:.6g}" for v in np.asarray(values)[order])
        out[per_frame(metric)] = f"[{text}]"  # bracketed: one frame's "1" stays text through a CSV
    return out


def _values(row: pd.Series, metric: Metric) -> np.ndarray | None:
    text = row.get(per_frame(metric))
    if not isinstance(text, str):
        return None
    return np.array(text.strip("[]").split(), dtype=float)


def paired(a: pd.Series, b: pd.Series, metric: Metric) -> stats.Paired | None:
    """Row `a` against row `b` on `metric`, frame by frame; None when they are not on the same frames (or either
    board predates per-frame values)."""
    if not isinstance(a.get(DIGEST), str) or a.get(DIGEST) != b.get(DIGEST):
        return None
    va, vb = _values(a, metric), _values(b, metric)
    if va is None or vb is None or not len(va) or len(va) != len(vb):
        return None
    if metric.aggregate == "proportion":
        return stats.mcnemar(va, vb)
    return stats.paired_bootstrap(va, vb)


def versus_above(board: pd.DataFrame, acc: Metric, tiebreak: Metric, sections: list[str]) -> list[str]:
    """Each row against the row ranked just above it in its section: McNemar on Acc. when their Acc. differs,
    else the paired bootstrap on the tie-break metric; "other frames" when they are not on the same frames."""
    verdicts = []
    for i in range(len(board)):
        row = board.iloc[i]
        above = board.iloc[i - 1] if i else None
        if above is None or any(str(row[c]) != str(above[c]) for c in sections):
            verdicts.append("")
            continue
        same_acc = row[acc.column] == above[acc.column]
        test = paired(above, row, tiebreak if same_acc else acc)
        if test is None:
            verdicts.append("other frames")
            continue
        named = f"{tiebreak.short} " if same_acc else ""
        verdicts.append(f"{'yes' if test.significant else 'no'} ({named}{test.test} p={test.p:.2g})")
    return verdicts
