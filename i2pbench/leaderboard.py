"""Leaderboards: one row per combination, weights and dataset split, aggregated from per-frame records.

Column names carry an arrow saying which direction is better (lm-eval's make_table). Latency columns are per frame,
in milliseconds, timed around each stage only.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .components import STAGE_ORDER
from .metrics import summarize
from .protocol import Protocol

GROUP = ["dataset", "split", "combination", "weights"]
ACC, RTE, RRE = "Acc. (%) ↑", "RTE (m) ↓", "RRE (°) ↓"
LATENCY_PREFIX = "latency"


def _pm(mean: float, std: float) -> str:
    return "-" if np.isnan(mean) else f"{mean:.2f} ± {std:.2f}"


def _row(records: pd.DataFrame, protocol: Protocol) -> dict:
    stats = summarize(records["rte_m"], records["rre_deg"], protocol)
    first = records.iloc[0]
    geo = records["geodesic_deg"].replace(np.inf, np.nan)
    row = {
        **{kind: first[kind] for kind in STAGE_ORDER},
        "weights_trained_on": first.get("weights_trained_on", ""),
        "frames": len(records),
        "failures": int((records["status"] != "ok").sum()),
        ACC: round(stats["acc_pct"], 2),
        RTE: _pm(stats["rte_mean"], stats["rte_std"]),
        RRE: _pm(stats["rre_mean"], stats["rre_std"]),
        "rte_mean": stats["rte_mean"],
        "rte_std": stats["rte_std"],
        "rre_mean": stats["rre_mean"],
        "rre_std": stats["rre_std"],
        "geodesic median (°) ↓": float(np.nanmedian(geo)) if geo.notna().any() else np.nan,
        "model size (MB) ↓": round(float(first["model_size_mb"]), 3),
        "latency median (ms) ↓": 1e3 * float(records["t_total_s"].median()),
        "latency p90 (ms) ↓": 1e3 * float(records["t_total_s"].quantile(0.9)),
    }
    for kind in STAGE_ORDER:
        column = f"t_{kind}_s"
        if column in records and records[column].notna().any():
            row[f"{LATENCY_PREFIX} {kind} (ms) ↓"] = 1e3 * float(records[column].median())
    return row


def build(records: pd.DataFrame, protocol: Protocol | None = None) -> pd.DataFrame:
    """Aggregate per-frame records into the leaderboard, best Acc. first."""
    protocol = protocol or Protocol()
    rows = [
        {**dict(zip(GROUP, key, strict=True)), **_row(group, protocol)}
        for key, group in records.groupby(GROUP, sort=False, dropna=False)
    ]
    board = pd.DataFrame(rows)
    return board.sort_values([ACC, "rre_mean"], ascending=[False, True], kind="stable").reset_index(drop=True)


DISPLAY = ["combination", "weights", "frames", "failures", ACC, RTE, RRE, "model size (MB) ↓", "latency median (ms) ↓"]


def to_markdown(board: pd.DataFrame, columns: list[str] | None = None) -> str:
    shown = board[[c for c in (columns or DISPLAY) if c in board]].copy()
    for column in shown.columns:
        if shown[column].dtype.kind == "f":
            shown[column] = shown[column].map(lambda v: "-" if pd.isna(v) else f"{v:.2f}")
    header = "| " + " | ".join(shown.columns) + " |"
    rule = "|" + "|".join("---" for _ in shown.columns) + "|"
    lines = ["| " + " | ".join(str(v) for v in row) + " |" for row in shown.itertuples(index=False)]
    return "\n".join([header, rule, *lines])


def write(board: pd.DataFrame, stem: str | Path) -> list[Path]:
    """Write `<stem>.csv`, `<stem>.md` and `<stem>.parquet`."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = [stem.with_suffix(".csv"), stem.with_suffix(".md"), stem.with_suffix(".parquet")]
    board.to_csv(paths[0], index=False)
    paths[1].write_text(to_markdown(board) + "\n")
    board.to_parquet(paths[2], index=False)
    return paths
