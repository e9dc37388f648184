"""The report's per-sequence section: each row's Acc. and error percentiles in each sequence (KITTI sequence or
drive; nuScenes camera), so a row that wins on average but fails one drive shows it."""

from __future__ import annotations

import pandas as pd

from ..scoring.installed import rescored
from ..scoring.protocol import Protocol
from ..scoring.recall import by_sequence

EXPLAIN = (
    "Each leaderboard row's frames by sequence (a KITTI sequence or drive, a nuScenes scene; nuScenes records "
    "written before runs recorded the scene go by camera), clean frames only, rows in the leaderboard's order; a row "
    "whose frames span several sequences has an 'all' line first. Percentiles are over all frames, a failure "
    "counting as an infinite error, and read one frame's error (no interpolation). The board's Parquet file holds "
    "the recall at several thresholds and the 25th to 90th percentiles over the whole run."
)


def table(records: pd.DataFrame, protocol: Protocol, order: list[tuple[str, str]]) -> pd.DataFrame:
    """by_sequence of the records as the run's card scores them, rows in `order` of (combination, weights) (the
    leaderboard's; the table's own order within a row: "all", then sequences by name)."""
    lines = by_sequence(rescored(records, protocol), protocol)
    rank = {key: i for i, key in enumerate(order)}
    keys = zip(lines["combination"], lines["weights"], strict=True)
    position = pd.Series([rank.get(key, len(rank)) for key in keys], index=lines.index)
    return lines.loc[position.sort_values(kind="stable").index].reset_index(drop=True)
