"""Figures for the report: cumulative error curves, Acc. against its thresholds, per-stage latency bars.

Every curve counts over ALL frames of a combination, failures included (a failure never falls under any threshold),
as Acc. does; so the curves end below 100 % when frames failed, and each Acc. curve passes through the leaderboard's
Acc. at the protocol's thresholds. Figures are built on matplotlib's object API (no pyplot), so no global backend
state is touched.
"""

from __future__ import annotations

import io

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

from ..boards.leaderboard import LATENCY_MEDIAN, stage_latency
from ..scoring.protocol import Protocol
from ..stages.components import STAGE_ORDER
from .labels import chars_in, line_count, number, tick, wrapped

ROW = ["combination", "weights"]  # one curve per leaderboard row of a dataset split
FIGURE_IN = 11.0  # every figure's width: the page's 1360 px column at 100 dpi, less its margins
LATENCY_LABEL_CHARS = 44  # a row's name beside the latency bars wraps here, leaving the bars ~3/4 of the width
BAR_SHARE = 0.75  # the slowest bar spans this share of the log axis; its value is written in the rest
TICKS = 7  # at most this many labelled decades on a log axis (more would crowd "1,000,000" into its neighbours)


def row_label(combination: str, weights: str) -> str:
    return combination if weights in ("none", "") else f"{combination} ({weights})"


def rows(
    records: pd.DataFrame, order: list[tuple[str, str]] | None = None, labels: dict | None = None
) -> list[tuple[str, pd.DataFrame]]:
    """[(label, records)] per (combination, weights), in `order` (e.g. the leaderboard's) when given (an empty
    order gives none); `labels` maps a key to its label (default `row_label`)."""
    groups = {key: group for key, group in records.groupby(ROW, sort=False)}
    keys = [k for k in order if k in groups] if order is not None else list(groups)
    labels = labels or {}
    return [(labels.get(key) or row_label(*key), groups[key]) for key in keys]


def cumulative_pct(errors: pd.Series, thresholds: np.ndarray) -> np.ndarray:
    """% of all frames whose error is at most each threshold (inf and NaN, i.e. failures, never are)."""
    values = np.sort(np.nan_to_num(errors.to_numpy(float), nan=np.inf))
    return 100.0 * np.searchsorted(values, thresholds, side="right") / max(len(values), 1)


def accuracy_pct(rte: pd.Series, rre: pd.Series, rte_max: np.ndarray, rre_max: np.ndarray) -> np.ndarray:
    """Acc. (%) with success = RTE < rte_max and RRE < rre_max, strict as the protocol's; thresholds broadcast."""
    rte, rre = rte.to_numpy(float)[:, None], rre.to_numpy(float)[:, None]
    ok = (rte < np.atleast_1d(rte_max)) & (rre < np.atleast_1d(rre_max))
    return 100.0 * ok.mean(axis=0) if len(rte) else np.full(np.broadcast(rte_max, rre_max).shape, np.nan)


def _axes(fig: Figure, titles: tuple[str, str], xlabels: tuple[str, str], ylabel: str):
    axes = fig.subplots(1, 2)
    for ax, title, xlabel in zip(axes, titles, xlabels, strict=True):
        ax.set(title=title, xlabel=xlabel, ylabel=ylabel, ylim=(-2, 102))
        ax.grid(True, which="both", alpha=0.3)
    return axes


def _legend(fig: Figure, axes) -> None:
    """Below both panels, one entry per row (names wrapped to the figure's width by `_legend_labels`)."""
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=1, fontsize=8, frameon=False)


def _figure(labels: list[str]) -> Figure:
    """Two panels side by side, taller by each legend line (the legend goes below both)."""
    lines = sum(line_count(label) for label in labels)
    return Figure(figsize=(FIGURE_IN, 3.8 + 0.17 * lines + 0.05 * len(labels)), layout="constrained")


def _legend_labels(groups: list[tuple[str, pd.DataFrame]]) -> list[str]:
    return [wrapped(label, chars_in(FIGURE_IN - 0.5)) for label, _ in groups]


def cumulative_errors(groups: list[tuple[str, pd.DataFrame]], protocol: Protocol) -> Figure:
    """% of frames under each RTE and RRE value (log axes), the protocol's thresholds dashed."""
    names = _legend_labels(groups)
    fig = _figure(names)
    axes = _axes(fig, ("Cumulative RTE", "Cumulative RRE"), ("RTE (m)", "RRE (°)"), "frames (%)")
    grids = (np.logspace(-3, 2, 400), np.logspace(-2, np.log10(360), 400))
    for label, (_, group) in zip(names, groups, strict=True):
        for ax, column, grid in zip(axes, ("rte_m", "rre_deg"), grids, strict=True):
            ax.plot(grid, cumulative_pct(group[column], grid), label=label)
    for ax, threshold, grid in zip(axes, (protocol.acc_rte_m, protocol.acc_rre_deg), grids, strict=True):
        ax.set_xscale("log")
        ax.set_xlim(grid[0], grid[-1])
        ax.axvline(threshold, color="k", linestyle="--", linewidth=0.8)
    _legend(fig, axes)
    return fig


def accuracy_curves(groups: list[tuple[str, pd.DataFrame]], protocol: Protocol) -> Figure:
    """Acc. against the RRE threshold at the protocol's RTE threshold, and against the RTE threshold at its RRE one."""
    names = _legend_labels(groups)
    fig = _figure(names)
    axes = _axes(
        fig,
        (
            f"Acc. vs RRE threshold (RTE < {protocol.acc_rte_m:g} m)",
            f"Acc. vs RTE threshold (RRE < {protocol.acc_rre_deg:g}°)",
        ),
        ("RRE threshold (°)", "RTE threshold (m)"),
        "Acc. (%)",
    )
    rre_grid = np.linspace(0, 4 * protocol.acc_rre_deg, 200)
    rte_grid = np.linspace(0, 4 * protocol.acc_rte_m, 200)
    for label, (_, g) in zip(names, groups, strict=True):
        axes[0].plot(rre_grid, accuracy_pct(g["rte_m"], g["rre_deg"], protocol.acc_rte_m, rre_grid), label=label)
        axes[1].plot(rte_grid, accuracy_pct(g["rte_m"], g["rre_deg"], rte_grid, protocol.acc_rre_deg), label=label)
    for ax, threshold in zip(axes, (protocol.acc_rre_deg, protocol.acc_rte_m), strict=True):
        ax.axvline(threshold, color="k", linestyle="--", linewidth=0.8)
    _legend(fig, axes)
    return fig


def latency_bars(board: pd.DataFrame, labels: list[str] | None = None) -> Figure:
    """Left: median milliseconds per frame per leaderboard row on a log axis, so a 20 ms row stays visible beside
    a 2 s one. Right: each stage's share of the row's summed stage medians (a stage absent from a row adds none).
    Row names are wrapped (the legends of the other figures carry them in full on one line where they fit)."""
    kinds = [k for k in STAGE_ORDER if stage_latency(k, "median") in board]
    labels = labels or [row_label(c, w) for c, w in zip(board["combination"], board["weights"], strict=True)]
    names = [wrapped(label, LATENCY_LABEL_CHARS) for label in labels]
    lines = sum(line_count(name) for name in names)
    fig = Figure(figsize=(FIGURE_IN, 1.9 + 0.15 * lines + 0.22 * len(names)), layout="constrained")
    fig.suptitle("Latency per frame: median total (left), share of each stage (right)")
    total_ax, share_ax = fig.subplots(1, 2, sharey=True, width_ratios=(3, 2))
    _totals(total_ax, board[LATENCY_MEDIAN].to_numpy(float))
    _shares(share_ax, board, kinds)
    total_ax.set_yticks(range(len(names)), names)
    total_ax.set_ylim(len(names) - 0.5, -0.5)  # leaderboard order, top to bottom (the axes share y)
    total_ax.tick_params(axis="y", labelsize=8)
    if kinds:
        fig.legend(fontsize=8, ncol=len(kinds), loc="outside lower center", frameon=False)
    return fig


def _totals(ax, total: np.ndarray) -> None:
    """Bars from a decade below the fastest row, each labelled with its median as the tables write it; the axis
    runs on past the slowest bar so its label stays inside the panel."""
    total = np.where(np.isfinite(total) & (total > 0), total, np.nan)
    timed = bool(np.isfinite(total).any())
    floor = 10.0 ** (np.floor(np.log10(np.nanmin(total))) - 1) if timed else 1.0
    top = floor * (np.nanmax(total) / floor) ** (1 / BAR_SHARE) if timed else 10.0
    bars = ax.barh(range(len(total)), total - floor, left=floor, color="0.45")
    ax.bar_label(bars, labels=[number(v, "ms") for v in total], fontsize=8, padding=3)
    ax.set_xscale("log")
    ax.set_xlim(floor, top)
    ax.xaxis.set_major_locator(LogLocator(numticks=TICKS))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: tick(v)))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set(xlabel="median latency per frame (ms, log scale)")
    ax.grid(True, axis="x", which="both", alpha=0.3)
    ax.set_axisbelow(True)


def _shares(ax, board: pd.DataFrame, kinds: list[str]) -> None:
    """Each stage's share of the row's summed stage medians, stacked in pipeline order."""
    ax.set(xlabel="share of the summed stage medians (%)", xlim=(0, 100))
    if not kinds:
        return
    stages = np.column_stack([board[stage_latency(k, "median")].fillna(0.0).to_numpy(float) for k in kinds])
    summed = stages.sum(axis=1)
    left = np.zeros(len(board))
    for i, kind in enumerate(kinds):
        share = np.divide(100.0 * stages[:, i], summed, out=np.zeros(len(board)), where=summed > 0)
        ax.barh(range(len(board)), share, left=left, label=kind)
        left += share


def png(fig: Figure, dpi: int = 100) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()
