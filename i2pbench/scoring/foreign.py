"""Predictions from another code base scored under protocol cards' rules, as a board (`i2pbench score`).

Each card's cells are the ones `i2pbench evaluate --rules` shows for a run holding the same poses (the same
`score.summarize`, the same formatting), plus the 95% intervals a leaderboard carries: Wilson for Acc., a seeded
percentile bootstrap of the mean for RTE and RRE over the frames the card's filter keeps.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from ..boards import stats
from . import cards, predictions
from .score import _below, frame_errors, summarize
from .table import columns, formatted

NEEDS_POSES = "needs poses"


def board(table: pd.DataFrame, wanted: list[cards.ProtocolCard]) -> pd.DataFrame:
    """A row per method: its frame count and, per card, Acc., RTE and RRE with their intervals."""
    rows = []
    for method, group in table.groupby("method", sort=False):
        row: dict[str, object] = {"method": method, "frames": len(group)}
        for card in wanted:
            row.update(card_cells(group, card))
        rows.append(row)
    return pd.DataFrame(rows)


def card_cells(group: pd.DataFrame, card: cards.ProtocolCard) -> dict[str, str]:
    errors = _errors(group, card.rules)
    if errors is None:
        return {card.name: NEEDS_POSES}
    with np.errstate(invalid="ignore", over="ignore"):
        cells = formatted(summarize(errors, card.rules), card.name)
    acc, rte, rre = columns(card.name)
    return {
        acc: cells[acc],
        f"{card.name} Acc. 95% CI": _acc_interval(errors, card.rules),
        rte: cells[rte],
        f"{card.name} RTE 95% CI": _mean_interval(errors, card.rules, "rte"),
        rre: cells[rre],
        f"{card.name} RRE 95% CI": _mean_interval(errors, card.rules, "rre"),
    }


def supports_errors_only(rules, any_failed: bool) -> bool:
    """Whether a card's rules can be applied to the peers' own RTE and RRE, without the poses: its errors are
    theirs, and nothing else needs a pose (a failure made the identity, DeepI2P's translation cap and inlier rule)."""
    failures = ("inf", "skip", "identity") if not any_failed else ("inf", "skip")
    return (rules.rre, rules.rte) == ("xzy-sum", "p-diff") and rules.failure in failures and (
        math.isinf(rules.max_translation_m) and not rules.drop_all_inliers
    )


def _errors(group: pd.DataFrame, rules) -> pd.DataFrame | None:
    if predictions.has_poses(group):
        return frame_errors(predictions.records(group), rules)
    rte, rre = group["rte"].to_numpy(float), group["rre"].to_numpy(float)
    failed = ~(np.isfinite(rte) & np.isfinite(rre))
    if not supports_errors_only(rules, bool(failed.any())):
        return None
    scored = ~failed | (rules.failure != "skip")
    return pd.DataFrame({"rte": rte, "rre": rre, "failed": failed, "scored": scored}, index=group.index)


def _acc_interval(errors: pd.DataFrame, rules) -> str:
    scored = errors[errors["scored"]]
    hits = int(((scored["rre"] < rules.acc_rre_deg) & (scored["rte"] < rules.acc_rte_m)).sum())
    low, high = stats.wilson(hits, len(scored))
    return _interval(100.0 * low, 100.0 * high)


def _mean_interval(errors: pd.DataFrame, rules, column: str) -> str:
    scored = errors[errors["scored"]]
    rte, rre = scored["rte"].to_numpy(float), scored["rre"].to_numpy(float)
    kept = _below(rte, rules.filter_rte_m) & _below(rre, rules.filter_rre_deg)
    return _interval(*stats.bootstrap_mean(scored[column].to_numpy(float)[kept]))


def _interval(low: float, high: float) -> str:
    return "-" if math.isnan(low) or math.isnan(high) else f"[{low:.2f}, {high:.2f}]"
