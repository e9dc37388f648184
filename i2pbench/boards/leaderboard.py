"""Leaderboards: one row per combination, weights and dataset split, aggregated from per-frame records.

Column names carry an arrow saying which direction is better (lm-eval's make_table). Latency columns are per frame,
in milliseconds, timed around each stage only (data loading, scoring and storing are outside), over the frames
whose pipeline ran to the end: a frame that crashed early would otherwise look fast.

Rows of a corrupted protocol carry its `corruption` and `severity` (both empty for clean rows); `robustness` turns
such a board into the summary per corruption: Acc. at each severity and their mean, and per row the mean over every
corruption and severity (mean corruption Acc., as ImageNet-C and KITTI-C average their grids).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from ..registry import build as registry_build
from ..registry.catalog import Registry
from ..scoring import installed as installed_metrics
from ..scoring import metrics as metric_registry
from ..scoring import recall
from ..scoring.cards import label
from ..scoring.installed import rescored
from ..scoring.metrics import (  # noqa: F401 (the board's column names, read from here by the other modules)
    ACC,
    ACC_SKILL,
    CHANCE,
    INLIER_RATIO,
    MIN_TRUE_MATCHES,
    RRE,
    RRE_MEAN,
    RTE,
    RTE_MEAN,
    TRUE_MATCHES,
    Metric,
)
from ..scoring.pose import kept
from ..scoring.protocol import Protocol
from ..stages.components import STAGE_ORDER
from . import uncertainty

GROUP = ["dataset", "split", "combination", "weights"]
CONDITION = ["corruption", "severity"]  # a row's protocol corruption; "" for clean rows
MODEL_SIZE = "model size (MB) ↓"
LATENCY_PREFIX = "latency"
LATENCY_MEDIAN, LATENCY_P90 = "latency median (ms) ↓", "latency p90 (ms) ↓"


def stage_latency(kind: str, stat: str) -> str:
    """Column name of one stage's latency statistic ("median" or "p90")."""
    return f"{LATENCY_PREFIX} {kind} {stat} (ms) ↓"


def _pm(mean: float, std: float) -> str:
    return "-" if np.isnan(mean) else f"{mean:.2f} ± {std:.2f}"


def _ms(seconds: pd.Series, q: float) -> float:
    seconds = seconds.dropna()
    return 1e3 * float(seconds.quantile(q)) if len(seconds) else np.nan


def _latency(records: pd.DataFrame) -> dict[str, float]:
    ran = records[records["failed_component"] == ""]
    row = {LATENCY_MEDIAN: _ms(ran["t_total_s"], 0.5), LATENCY_P90: _ms(ran["t_total_s"], 0.9)}
    for kind in STAGE_ORDER:
        column = f"t_{kind}_s"
        if column in ran and ran[column].notna().any():
            row[stage_latency(kind, "median")] = _ms(ran[column], 0.5)
            row[stage_latency(kind, "p90")] = _ms(ran[column], 0.9)
    return row


def _metric_cells(records: pd.DataFrame, protocol: Protocol, metrics: tuple[Metric, ...]) -> dict:
    """Each registered metric's aggregate under its column (and a mean's std and "mean ± std" text columns)."""
    named = installed_metrics.aggregates(records, protocol, metrics)
    cells: dict = {}
    for metric in (m for m in metrics if m.column is not None):
        cells[metric.column] = named[metric.name]
        if metric.std:
            cells[metric.std] = named[metric.std]
        if metric.summary:
            cells[metric.summary] = _pm(named[metric.name], named.get(metric.std, np.nan))
    return cells


# The columns boards had before metrics were registered, in their order: a board keeps it, and what is new follows.
ORDER = [ACC, RTE, RRE, RTE_MEAN, "rte_std", RRE_MEAN, "rre_std", metric_registry.GEODESIC_MEDIAN, INLIER_RATIO,
         TRUE_MATCHES, CHANCE, ACC_SKILL]  # fmt: skip


def _row(records: pd.DataFrame, protocol: Protocol, metrics: tuple[Metric, ...]) -> dict:
    first = records.iloc[0]
    cells = _metric_cells(records, protocol, metrics)
    return {
        **{kind: first[kind] for kind in STAGE_ORDER},
        "weights_trained_on": first.get("weights_trained_on", ""),
        "frames": len(records),
        "failures": int((records["status"] != "ok").sum()),
        # frames inside the protocol's filter, over which RTE and RRE are averaged
        "kept": int(kept(records["rte_m"], records["rre_deg"], protocol).sum()),
        **{column: cells.pop(column) for column in ORDER if column in cells},
        MODEL_SIZE: round(float(first["model_size_mb"]), 3),
        **_latency(records),
        **cells,  # the metrics plugins register
        **recall.cells(records, protocol),  # registration recall at several thresholds, error percentiles
        **uncertainty.cells(records, protocol, metrics),
    }


def build(
    records: pd.DataFrame,
    protocol: Protocol | None = None,
    metrics: tuple[Metric, ...] | None = None,
    registry: Registry | None = None,
) -> pd.DataFrame:
    """Aggregate per-frame records into the leaderboard, one column per metric (`metrics`, default the registry's:
    the built-in ones and its plugins'): clean rows first, then each corruption (in run order) by severity, and
    within each of those best Acc. first. `registry` (default: the installed plugins') also names each row's
    method."""
    protocol = protocol or Protocol()
    registry = registry or registry_build.default_registry()
    metrics = metrics if metrics is not None else installed_metrics.active(registry)
    records = rescored(_with_condition(records), protocol)  # a non-default card's rules (scoring.cards)
    rows = [
        {**dict(zip(GROUP + CONDITION, key, strict=True)), **_row(group, protocol, metrics)}
        for key, group in records.groupby(GROUP + CONDITION, sort=False, dropna=False)
    ]
    board = pd.DataFrame(rows)
    board = board.sort_values([ACC, RRE_MEAN], ascending=[False, True], kind="stable")
    order = {name: i for i, name in enumerate(pd.unique(records["corruption"]), start=1)}
    rank = board["corruption"].map(lambda c: 0 if c == "" else order[c]) * 100 + board["severity"]
    board = board.iloc[np.argsort(rank.to_numpy(), kind="stable")].reset_index(drop=True)
    board["severity"] = [str(int(v)) if c else "" for c, v in zip(board["corruption"], board["severity"], strict=True)]
    board["method"] = _methods(board, registry)
    board["protocol"] = label(protocol)  # the card and its version
    named = {m.name: m for m in metrics}
    if "acc_pct" in named and "rre_mean" in named:  # rows are ranked by these two
        board[uncertainty.VERSUS] = uncertainty.versus_above(board, named["acc_pct"], named["rre_mean"], CONDITION)
    return board[[*GROUP, *CONDITION, *(c for c in board.columns if c not in GROUP + CONDITION)]]


def _methods(board: pd.DataFrame, registry: Registry) -> list[str]:
    """Each row's method (DeepI2P, EdgeRegNet, ...; "classic" for the classic plugin's matchers), as the registry's
    plugins declare them (`methods.method_of`)."""
    from ..registry.methods import method_of

    methods, owner = dict(registry.methods), registry.components["matcher"].owners()
    stages = board[list(STAGE_ORDER)].astype(str).to_dict("records")
    return [method_of(methods, owner, row) for row in stages]


def _with_condition(records: pd.DataFrame) -> pd.DataFrame:
    """Records written before corruptions existed are clean."""
    if "corruption" not in records:
        records = records.assign(corruption="")
    if "severity" not in records:
        records = records.assign(severity=0)
    return records.assign(corruption=records["corruption"].fillna(""), severity=records["severity"].fillna(0))


def latency_columns(board: pd.DataFrame) -> list[str]:
    """The machine-dependent columns: everything else must agree between two runs with the same seed."""
    return [c for c in board.columns if c.startswith(LATENCY_PREFIX)]


def _displayed(columns: list[str], metrics: tuple[Metric, ...]) -> list[str]:
    """`columns` with each of `metrics`' interval after it (after its "mean ± std" text for RTE and RRE), and after
    Acc. the verdict against the row above."""
    after: dict[str, list[str]] = {}
    for metric in uncertainty.with_interval(metrics):
        after.setdefault(metric.summary or metric.column, []).append(uncertainty.ci(metric))
    after.setdefault(ACC, []).append(uncertainty.VERSUS)
    return [name for column in columns for name in (column, *after.get(column, []))]


DISPLAY = _displayed(
    ["dataset", "split", "combination", "method", "corruption", "severity", "weights", "weights_trained_on", "frames",
     "failures", ACC, CHANCE, ACC_SKILL, RTE, RRE, INLIER_RATIO, TRUE_MATCHES, MODEL_SIZE, LATENCY_MEDIAN, LATENCY_P90],
    metric_registry.BUILTIN,
)  # fmt: skip


def to_markdown(
    board: pd.DataFrame, columns: list[str] | None = None, metrics: tuple[Metric, ...] | None = None
) -> str:
    """A Markdown table of `columns` (default DISPLAY, then the columns of the plugins' metrics among `metrics`,
    default the installed ones, with their intervals, less the columns that are empty in every row)."""
    if columns is None:
        plugins = (metrics or installed_metrics.active())[len(metric_registry.BUILTIN) :]
        extra = _displayed([m.column for m in plugins if m.column], plugins)
        columns = [c for c in DISPLAY + extra if c in board and not (board[c].astype(str) == "").all()]
    shown = board[[c for c in columns if c in board]].copy()
    for column in shown.columns:
        if shown[column].dtype.kind == "f":
            shown[column] = shown[column].map(lambda v: "-" if pd.isna(v) else f"{v:.2f}")
    header = "| " + " | ".join(shown.columns) + " |"
    rule = "|" + "|".join("---" for _ in shown.columns) + "|"
    lines = ["| " + " | ".join(str(v) for v in row) + " |" for row in shown.itertuples(index=False)]
    return "\n".join([header, rule, *lines])


def write(board: pd.DataFrame, stem: str | Path, metrics: tuple[Metric, ...] | None = None) -> list[Path]:
    """Write `<stem>.csv`, `<stem>.md` (`to_markdown`'s columns for `metrics`) and `<stem>.parquet`, each atomically
    (a reader never sees half a table)."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = [stem.with_name(f"{stem.name}.{ext}") for ext in ("csv", "md", "parquet")]
    writers = (
        lambda p: board.to_csv(p, index=False, na_rep="nan"),  # an explicit NaN, so "" stays an empty string
        lambda p: p.write_text(to_markdown(board, metrics=metrics) + "\n"),
        lambda p: board.to_parquet(p, index=False),
    )
    for path, writer in zip(paths, writers, strict=True):
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        writer(tmp)
        os.replace(tmp, path)
    return paths


def read(path: str | Path) -> pd.DataFrame:
    """A leaderboard written by `write`, from its CSV or Parquet file."""
    path = Path(path)
    if path.suffix == ".parquet":
        return pd.read_parquet(path)
    return pd.read_csv(path, keep_default_na=False, na_values=["nan"])


CLEAN_ACC, MEAN_ACC, RETAINED = "clean Acc. (%) ↑", "mean Acc. (%) ↑", "retained (%) ↑"
MEAN_ROW = "mean corruption Acc."  # the summary row averaging every corruption and severity


def severity_column(severity: int) -> str:
    return f"severity {severity} Acc. (%) ↑"


def robustness(board: pd.DataFrame, kinds: dict[str, str] | None = None) -> pd.DataFrame:
    """Per row (combination, weights, dataset split) and corruption: Acc. at each severity, their mean and the clean
    Acc.; then a `MEAN_ROW` whose severity columns average the corruptions and whose mean is the mean corruption Acc.
    over every corruption and severity run. `retained` is mean / clean. `kinds` maps corruptions to their kind."""
    corrupted = board[board["corruption"] != ""]
    severities = sorted({int(s) for s in corrupted["severity"]})
    rows = []
    for key, group in corrupted.groupby(GROUP, sort=False):
        clean = board[(board[GROUP] == pd.Series(key, index=GROUP)).all(axis=1) & (board["corruption"] == "")]
        reference = float(clean[ACC].iloc[0]) if len(clean) else np.nan
        cells = group.assign(severity=group["severity"].astype(int)).pivot_table(
            index="corruption", columns="severity", values=ACC, aggfunc="first", sort=False
        )
        for name, accs in [*cells.iterrows(), (MEAN_ROW, cells.mean())]:
            mean = float(np.nanmean(cells.to_numpy())) if name == MEAN_ROW else float(accs.mean())
            rows.append({
                **dict(zip(GROUP, key, strict=True)),
                "corruption": name,
                "kind": (kinds or {}).get(name, ""),
                CLEAN_ACC: reference,
                **{severity_column(s): float(accs.get(s, np.nan)) for s in severities},
                MEAN_ACC: round(mean, 2),
                RETAINED: round(100.0 * mean / reference, 2) if reference else np.nan,
            })  # fmt: skip
    return pd.DataFrame(rows)


def write_robustness(summary: pd.DataFrame, stem: str | Path) -> list[Path]:
    """Write `<stem>.csv` and `<stem>.md` (every column), atomically as `write` does."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    columns = [c for c in summary.columns if not (c == "kind" and (summary[c] == "").all())]
    writers = {
        "csv": lambda p: summary.to_csv(p, index=False, na_rep="nan"),
        "md": lambda p: p.write_text(to_markdown(summary, columns) + "\n"),
    }
    paths = []
    for ext, writer in writers.items():
        path = stem.with_name(f"{stem.name}.{ext}")
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        writer(tmp)
        os.replace(tmp, path)
        paths.append(path)
    return paths
