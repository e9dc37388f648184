"""A paper-style comparison table: a preset's rows (methods) down, one column group per dataset across.

A leaderboard holds one dataset split; a paper's comparison (the seed's Table I) puts methods in rows and datasets
side by side. `build` reads one leaderboard per dataset and finds each preset row in each by its combination label
(the clean protocol only), so the table shows what the leaderboards measured and nothing recomputed: per dataset
RTE, RRE, Acc. with its chance successes, Acc. with true matches, true matches and latency; once per row the
weights and model size.
A row a board lacks is "not run" there, never silently zero. Where a board keeps per-frame values, each row's Acc.
is tested against the row above it on the same frames (McNemar's exact test): `<dataset> Acc. vs row above` says
whether the two differ significantly, so a reader does not take a one-frame gap for a ranking.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from ..errors import I2PBenchError
from ..registry.catalog import Registry
from ..runs.grid import expand
from ..scoring import installed as installed_metrics
from . import uncertainty
from .leaderboard import ACC, ACC_SKILL, CHANCE, LATENCY_MEDIAN, MODEL_SIZE, RRE, RTE, TRUE_MATCHES, to_markdown

PER_DATASET = ("frames", RTE, RRE, ACC, CHANCE, ACC_SKILL, TRUE_MATCHES, LATENCY_MEDIAN)
COUNTS = ("frames", CHANCE)  # shown as whole numbers
NOT_RUN = "not run"
VERSUS = "Acc. vs row above"


@dataclass(frozen=True)
class TableRow:
    """One row: the preset entry it comes from (an included preset's name, or a combination) and its board label."""

    name: str
    label: str  # the leaderboard's `combination` column for this row
    description: str = ""


def preset_rows(registry: Registry, preset: str) -> list[TableRow]:
    """The preset's rows in its own order, each named by the preset entry that contributes it."""
    rows: list[TableRow] = []
    for entry in registry.preset(preset).combinations:
        if isinstance(entry, str):
            combinations = expand(registry.preset_rows(entry), {}, registry=registry)
            included = registry.preset(entry)
            name = f"{included.method} ({entry})" if included.method and included.method != entry else entry
            description = included.description
        else:
            row = registry.row(entry)  # None: a row of a method no loaded plugin registers
            combinations, description = expand([row] if row else [], {}, registry=registry), ""
            name = ""
        for combination in combinations:
            label = combination.display
            shown = f"{name}: {label}" if name and len(combinations) > 1 else name or label
            rows.append(TableRow(shown, label, description))
    return rows


def build(rows: list[TableRow], boards: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """Rows down, `PER_DATASET` columns per board (named "<dataset> <column>") across, weights and size once."""
    if not boards:
        raise I2PBenchError("a comparison table needs at least one leaderboard (DATASET=PATH)")
    out, found_rows = [], {dataset: [] for dataset in boards}
    for row in rows:
        cells: dict[str, object] = {"method": row.name}
        weights, trained_on, sizes = [], [], []
        for dataset, board in boards.items():
            found = _clean(board)[lambda b, label=row.label: b["combination"] == label]
            if found.empty:
                cells.update({f"{dataset} {column}": None for column in PER_DATASET})
                found_rows[dataset].append(None)
                continue
            if len(found) > 1:  # one label, several weights: which row the table shows would be a guess
                shown = ", ".join(map(str, found["weights"]))
                raise I2PBenchError(f"leaderboard of {dataset} has {len(found)} rows {row.label!r} ({shown})")
            first = found.iloc[0]
            found_rows[dataset].append(first)
            cells.update({f"{dataset} {column}": first.get(column) for column in PER_DATASET})
            weights.append(str(first.get("weights", "")))
            trained_on.append(str(first.get("weights_trained_on", "")))
            sizes.append(first.get(MODEL_SIZE))
        cells["weights"] = " / ".join(dict.fromkeys(w for w in weights if w)) or NOT_RUN
        cells["weights_trained_on"] = " / ".join(dict.fromkeys(t for t in trained_on if t and t != "nan"))
        cells[MODEL_SIZE] = sizes[0] if sizes else None
        cells["combination"] = row.label
        out.append(cells)
    table = pd.DataFrame(out)
    for dataset, found in found_rows.items():
        table[f"{dataset} {VERSUS}"] = _versus_above(found)
    return table


def _versus_above(rows: list[pd.Series | None]) -> list[str]:
    """Each row's Acc. against the row above on one dataset: "no (McNemar p=...)" when the difference is not
    significant, "yes (...)" when it is, "" where either row is missing or the boards keep no per-frame values."""
    acc = installed_metrics.by_name()["acc_pct"]
    out = [""]
    for above, row in zip(rows, rows[1:], strict=False):
        test = uncertainty.paired(above, row, acc) if above is not None and row is not None else None
        out.append("" if test is None else f"{'yes' if test.significant else 'no'} ({test.test} p={test.p:.2g})")
    return out[: len(rows)]


def _clean(board: pd.DataFrame) -> pd.DataFrame:
    """The rows of the uncorrupted protocol (a robustness board also holds corrupted ones)."""
    if "corruption" not in board:
        return board
    corruption = board["corruption"].fillna("").astype(str)
    return board[corruption.isin(["", "nan"])]


def missing(table: pd.DataFrame, datasets: list[str]) -> dict[str, list[str]]:
    """dataset -> the rows its leaderboard lacks."""
    return {d: list(table.loc[table[f"{d} frames"].isna(), "method"]) for d in datasets}


def to_text(table: pd.DataFrame, rows: list[TableRow], sources: dict[str, str]) -> str:
    """The Markdown table, then where each dataset's numbers come from, the rows it lacks and what each row is."""
    untested = [c for c in table.columns if c.endswith(VERSUS) and not table[c].astype(bool).any()]
    shown = _shown(table.drop(columns=["combination", *untested]))
    lines = [to_markdown(shown, list(shown.columns)), ""]
    for dataset, lacking in missing(table, list(sources)).items():
        absent = f"; {NOT_RUN} there: {', '.join(lacking)}" if lacking else ""
        lines.append(f"- {dataset}: `{sources[dataset]}`{absent}")
    lines += [f"- {row.name}: {row.description}" for row in rows if row.description]
    return "\n".join(lines)


def _shown(table: pd.DataFrame) -> pd.DataFrame:
    """Cells as text: counts whole, other numbers to two decimals, a missing cell "-"."""
    shown = table.astype(object)
    for column in table.columns:
        whole = column.endswith(COUNTS)
        shown[column] = table[column].map(lambda v, whole=whole: _cell(v, whole))
    return shown


def _cell(value: object, whole: bool) -> str:
    if value is None or (isinstance(value, float) and pd.isna(value)):
        return "-"
    if isinstance(value, int | float) and not isinstance(value, bool):
        return f"{value:.0f}" if whole else f"{value:.2f}"
    return str(value)


def write(table: pd.DataFrame, text: str, stem: str | Path) -> list[Path]:
    """`<stem>.csv` (the numbers) and `<stem>.md` (the table and its notes)."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    csv, md = stem.with_name(f"{stem.name}.csv"), stem.with_name(f"{stem.name}.md")
    table.to_csv(csv, index=False, na_rep="nan")
    md.write_text(text + "\n")
    return [csv, md]
