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
from matplotlib.ticker import FuncFormatter

from ..boards.leaderboard import LATENCY_MEDIAN, stage_latency
from ..components import STAGE_ORDER
from ..protocol import Protocol

ROW = ["combination", "weights"]  # one curve per leaderboard row of a dataset split


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
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=1, fontsize=8, frameon=False)


def _figure(n_rows: int) -> Figure:
    """Two panels side by side, taller by one legend line per row (the legend goes below both)."""
    return Figure(figsize=(11, 3.8 + 0.2 * n_rows), layout="constrained")


def cumulative_errors(groups: list[tuple[str, pd.DataFrame]], protocol: Protocol) -> Figure:
    """% of frames under each RTE and RRE value (log axes), the protocol's thresholds dashed."""
    fig = _figure(len(groups))
    axes = _axes(fig, ("Cumulative RTE", "Cumulative RRE"), ("RTE (m)", "RRE (°)"), "frames (%)")
    grids = (np.logspace(-3, 2, 400), np.logspace(-2, np.log10(360), 400))
    for label, group in groups:
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
    fig = _figure(len(groups))
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
    for label, g in groups:
        axes[0].plot(rre_grid, accuracy_pct(g["rte_m"], g["rre_deg"], protocol.acc_rte_m, rre_grid), label=label)
        axes[1].plot(rte_grid, accuracy_pct(g["rte_m"], g["rre_deg"], rte_grid, protocol.acc_rre_deg), label=label)
    for ax, threshold in zip(axes, (protocol.acc_rre_deg, protocol.acc_rte_m), strict=True):
        ax.axvline(threshold, color="k", linestyle="--", linewidth=0.8)
    _legend(fig, axes)
    return fig


def latency_bars(board: pd.DataFrame, labels: list[str] | None = None) -> Figure:
    """Left: median milliseconds per frame per leaderboard row on a log axis, so a 20 ms row stays visible beside
    a 2 s one. Right: each stage's share of the row's summed stage medians (a stage absent from a row adds none)."""
    kinds = [k for k in STAGE_ORDER if stage_latency(k, "median") in board]
    labels = labels or [row_label(c, w) for c, w in zip(board["combination"], board["weights"], strict=True)]
    fig = Figure(figsize=(11, 2.4 + 0.4 * len(board)), layout="constrained")
    fig.suptitle("Latency per frame: median total (left), share of each stage (right)")
    total_ax, share_ax = fig.subplots(1, 2, sharey=True, width_ratios=(3, 2))
    total = board[LATENCY_MEDIAN].to_numpy(float)
    total = np.where(np.isfinite(total) & (total > 0), total, np.nan)
    floor = 10.0 ** (np.floor(np.log10(np.nanmin(total))) - 1) if np.isfinite(total).any() else 1.0
    bars = total_ax.barh(labels, total - floor, left=floor, color="0.45")  # from a decade below the fastest
    total_ax.bar_label(bars, labels=[f"{v:.3g} ms" if np.isfinite(v) else "-" for v in total], fontsize=8, padding=2)
    total_ax.set_xscale("log")
    total_ax.set_xlim(floor, 10.0 ** np.ceil(np.log10(np.nanmax(total) * 3)) if np.isfinite(total).any() else 10.0)
    total_ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    total_ax.set(xlabel="median latency per frame (ms, log scale)")
    total_ax.grid(True, axis="x", which="both", alpha=0.3)
    total_ax.set_axisbelow(True)
    stages = np.column_stack([board[stage_latency(k, "median")].fillna(0.0).to_numpy(float) for k in kinds] or [])
    left = np.zeros(len(board))
    for i, kind in enumerate(kinds):
        summed = stages.sum(axis=1)
        share = np.divide(100.0 * stages[:, i], summed, out=np.zeros(len(board)), where=summed > 0)
        share_ax.barh(labels, share, left=left, label=kind)
        left += share
    share_ax.set(xlabel="share of the summed stage medians (%)", xlim=(0, 100))
    total_ax.invert_yaxis()  # leaderboard order, top to bottom (the axes share y)
    total_ax.tick_params(axis="y", labelsize=8)
    if kinds:
        fig.legend(fontsize=8, ncol=len(kinds), loc="outside lower center", frameon=False)
    return fig


def png(fig: Figure, dpi: int = 100) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()
