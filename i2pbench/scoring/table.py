"""One finished run scored under several protocol cards' rules: `i2pbench evaluate RUN --rules all`.

Rows are the run's leaderboard rows (combination, weights, corruption); each card adds three columns, its Acc., RTE
and RRE (mean ± std) by its own rules. A card whose inputs differ from those the run's stages were given has one
column instead, "needs a rerun": its numbers would describe other predictions than these. `rules_only` scores
those cards anyway, by their rules alone, and says so (the table's `note`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pandas as pd

from ..errors import I2PBenchError
from . import cards, installed
from .protocol import Protocol
from .score import score

NEEDS_RERUN = "needs a rerun"
ROW = ["combination", "weights", "corruption", "severity"]


@dataclass
class RulesTable:
    table: pd.DataFrame  # a row per leaderboard row; per card "<name> Acc. (%)", "... RTE (m)", "... RRE (°)"
    scored: list[str]  # cards scored with the run's own inputs
    rules_only: list[str]  # cards whose inputs differ, scored by their rules alone (rules_only=True)
    rerun: dict[str, list[str]]  # cards whose inputs differ, left unscored: name -> the differences


def columns(name: str) -> list[str]:
    return [f"{name} Acc. (%)", f"{name} RTE (m)", f"{name} RRE (°)"]


def chosen(names: str) -> list[cards.ProtocolCard]:
    """The cards `--rules` names: comma-separated names, or `all` (every installed card, the default first)."""
    if names == "all":
        return list(installed.installed().values())
    wanted = [installed.find(name.strip()) for name in names.split(",") if name.strip()]
    if not wanted:
        known = ", ".join(installed.installed())
        raise I2PBenchError(f"--rules {names!r} names no protocol card; give names ({known}) or all")
    return wanted


def rules_table(records: pd.DataFrame, protocol: Protocol, wanted: list[cards.ProtocolCard],
                rules_only: bool = False) -> RulesTable:  # fmt: skip
    """The records (one run's, under `protocol`) scored under each wanted card's rules."""
    if records.empty:
        raise I2PBenchError("no per-frame records to score")
    dataset = str(records["dataset"].iloc[0])
    given = installed.of(protocol).inputs(dataset)
    result = RulesTable(pd.DataFrame(), [], [], {})
    for card in wanted:
        if given is not None and card.inputs(dataset) == given:
            result.scored.append(card.name)
        elif rules_only:
            result.rules_only.append(card.name)
        else:
            inputs = card.inputs(dataset)
            result.rerun[card.name] = card.unmet(dataset) if inputs is None else inputs.differences(given, "this run")
    rows = []
    for key, group in _with_condition(records).groupby(ROW, sort=False, dropna=False):
        row = dict(zip(ROW, key, strict=True))
        row["severity"] = str(int(row["severity"])) if row["corruption"] else ""
        row["frames"] = len(group)
        for card in wanted:
            row.update({card.name: NEEDS_RERUN} if card.name in result.rerun else _cells(group, card))
        rows.append(row)
    table = pd.DataFrame(rows)
    result.table = table.drop(columns=[c for c in ("corruption", "severity") if (table[c] == "").all()])
    return result


def _with_condition(records: pd.DataFrame) -> pd.DataFrame:
    """Records written before corruptions existed are clean."""
    extra = {k: v for k, v in (("corruption", ""), ("severity", 0)) if k not in records}
    records = records.assign(**extra)
    return records.assign(corruption=records["corruption"].fillna(""), severity=records["severity"].fillna(0))


def _cells(records: pd.DataFrame, card: cards.ProtocolCard) -> dict[str, str]:
    return formatted(score(records, card.rules), card.name)


def formatted(stats: dict[str, float], name: str) -> dict[str, str]:
    """A card's three cells as the table shows them, from `score.summarize`'s numbers."""
    acc, rte, rre = columns(name)
    return {
        acc: "-" if math.isnan(stats["acc_pct"]) else f"{stats['acc_pct']:.2f}",
        rte: _pm(stats["rte_mean"], stats["rte_std"]),
        rre: _pm(stats["rre_mean"], stats["rre_std"]),
    }


def _pm(mean: float, std: float) -> str:
    if math.isnan(mean):
        return "-"
    return "inf" if math.isinf(mean) else f"{mean:.2f} ± {std:.2f}"


def to_markdown(table: pd.DataFrame) -> str:
    header = "| " + " | ".join(table.columns) + " |"
    rule = "|" + "|".join("---" for _ in table.columns) + "|"
    lines = ["| " + " | ".join(str(v) for v in row) + " |" for row in table.itertuples(index=False)]
    return "\n".join([header, rule, *lines])


def notes(result: RulesTable, protocol: Protocol) -> list[str]:
    """What the table's reader must know: which cards were scored how, and why the others were not."""
    out = [f"run under {cards.label(protocol)}; scored with the run's inputs: {', '.join(result.scored) or 'none'}"]
    if result.rules_only:
        out.append(f"scored by their rules alone, although their inputs differ from the run's (--rules-only): "
                   f"{', '.join(result.rules_only)}")  # fmt: skip
    for name, unmet in result.rerun.items():
        out.append(f"{name}: {NEEDS_RERUN} ({'; '.join(unmet)})")
    return out
