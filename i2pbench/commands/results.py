"""What the Python calls (`i2pbench.run`, `evaluate`, `compare`, `score`) return: the tables as pandas DataFrames and
where they were stored, so a notebook reads no file back. The CLI makes the same objects and prints them."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd


@dataclass
class RunResult:
    """A finished `run`: its leaderboard, its grid's per-frame records, and where both were stored."""

    board: pd.DataFrame  # one row per combination (and condition), the leaderboard's columns
    records: pd.DataFrame  # one row per frame and combination, the store's columns (T_pred, T_gt, rte, rre, ...)
    run_dir: Path  # the per-frame results store (runs/<dataset>-<split>)
    files: list[Path]  # the leaderboard files written (STEM.csv, .md, .parquet, .env.json, ...)
    invocation: str  # this run's id in run_dir/invocations


@dataclass
class EvaluateResult:
    """A leaderboard recomputed from a store: the board (or, with rules, the table of every card's numbers)."""

    board: pd.DataFrame
    records: pd.DataFrame  # the records it was computed from
    run_dir: Path
    files: list[Path] = field(default_factory=list)  # written with out=STEM, else none
    notes: list[str] = field(default_factory=list)  # with rules: which cards were scored how, and why not the others
    by_sequence: pd.DataFrame | None = None  # with by_sequence=True: each row's Acc. and percentiles per sequence


@dataclass
class CompareResult:
    """The regression gate's verdict on a new leaderboard against a baseline."""

    ok: bool  # no baseline row regressed or went missing
    report: str  # the text `i2pbench compare` prints
    findings: list = field(default_factory=list)  # regression_gate.Finding, one per failed check


@dataclass
class ScoreResult:
    """Another code base's per-frame predictions scored under protocol cards' rules, as a board."""

    board: pd.DataFrame  # a row per method (and sequence 'all'); per card Acc. and RTE/RRE with their intervals
    predictions: pd.DataFrame  # the predictions as read and checked, in the documented schema
    files: list[Path] = field(default_factory=list)
