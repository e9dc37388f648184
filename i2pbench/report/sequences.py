"""The report's per-sequence section: each row's Acc. and error percentiles in each sequence (KITTI sequence or
drive; nuScenes camera), so a row that wins on average but fails one drive shows it."""

from __future__ import annotations

import pandas as pd

from ..protocol import Protocol
from ..scoring.installed import rescored
from ..scoring.recall import by_sequence

EXPLAIN = (
    "Each row's frames by sequence (a KITTI sequence or drive, a nuScenes scene; nuScenes records written before "
    "runs recorded the scene go by camera), clean frames only. Percentiles are over all frames, a failure counting "
    "as an infinite error, and read one frame's error (no interpolation). The board's Parquet file holds the recall "
    "at several thresholds and the 25th to 90th percentiles over the whole run."
)


def table(records: pd.DataFrame, protocol: Protocol, labels: dict) -> pd.DataFrame:
    """by_sequence of the records as the run's card scores them, with the figures' row labels."""

    def name(combination: str, weights: str) -> str:
        return labels.get((combination, weights), combination)

    return by_sequence(rescored(records, protocol), protocol, name)
