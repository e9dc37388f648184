"""Registration recall at several thresholds, error percentiles, and the same per sequence.

Recall at an RRE threshold is the share of ALL frames with RRE below it and RTE below the protocol's Acc. threshold
(and the other way round for RTE), so each recall column at the protocol's own thresholds is its Acc. Percentiles
are over all frames with a failure an infinite error (its quantile is then "inf", never a number a failure lowered)
and take the frame at that rank (numpy's inverted_cdf: no interpolation, so a percentile is some frame's error).
A frame's sequence is what its dataset recorded (`Dataset.sequence_of`: a KITTI sequence or drive, the synthetic
streets' sequence, a nuScenes scene); for records written before that column, the frame id's part before the "/",
or for nuScenes, whose frame id ("<sample token>/<camera>") names no scene, the camera.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .protocol import Protocol

RRE_STEPS_DEG = (1.0, 2.0, 5.0, 10.0, 20.0)
RTE_STEPS_M = (0.25, 0.5, 1.0, 2.0, 5.0)
PERCENTILES = (25, 50, 75, 90)


def recall_column(error: str, threshold: float) -> str:
    return f"recall RRE<{threshold:g}° (%)" if error == "rre" else f"recall RTE<{threshold:g} m (%)"


def percentile_column(error: str, q: int) -> str:
    return f"RRE p{q} (°)" if error == "rre" else f"RTE p{q} (m)"


def _errors(records: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """RTE and RRE with NaN (no error recorded) read as infinite, a failure."""
    rte, rre = records["rte_m"].to_numpy(float), records["rre_deg"].to_numpy(float)
    return np.where(np.isnan(rte), np.inf, rte), np.where(np.isnan(rre), np.inf, rre)


def percentile(values: np.ndarray, q: int) -> float:
    return float(np.percentile(values, q, method="inverted_cdf")) if len(values) else np.nan


def cells(records: pd.DataFrame, protocol: Protocol) -> dict[str, float]:
    """A leaderboard row's recall and percentile columns."""
    rte, rre = _errors(records)
    n = max(len(rte), 1)
    out = {}
    for t in RRE_STEPS_DEG:
        out[recall_column("rre", t)] = round(100.0 * float(((rre < t) & (rte < protocol.acc_rte_m)).sum()) / n, 2)
    for t in RTE_STEPS_M:
        out[recall_column("rte", t)] = round(100.0 * float(((rte < t) & (rre < protocol.acc_rre_deg)).sum()) / n, 2)
    for q in PERCENTILES:
        out[percentile_column("rte", q)] = percentile(rte, q)
        out[percentile_column("rre", q)] = percentile(rre, q)
    return out


def sequence(dataset: str, frame_id: str) -> str:
    head, _, tail = str(frame_id).partition("/")
    return f"camera {tail}" if dataset.startswith("nuscenes") else head


def sequences(records: pd.DataFrame) -> list[str]:
    """Each record's sequence: as its dataset recorded it (`Dataset.sequence_of`: a nuScenes scene), else, for
    records written before, read from its frame id."""
    stored = records["sequence"] if "sequence" in records else pd.Series("", index=records.index)
    return [
        s if isinstance(s, str) and s else sequence(d, f)
        for s, d, f in zip(stored, records["dataset"], records["frame_id"], strict=True)
    ]


SEQUENCE_ROW = ["combination", "weights", "sequence"]  # what each line of the per-sequence table is about
SEQUENCE_COLUMNS = ["frames", "Acc. (%) ↑", "RTE p50 (m)", "RTE p90 (m)", "RRE p50 (°)", "RRE p90 (°)"]
ALL = "all"  # the sequence of a row's line over all its frames


def by_sequence(records: pd.DataFrame, protocol: Protocol) -> pd.DataFrame:
    """One line per leaderboard row (combination, weights) and sequence: frames, Acc. and the RTE and RRE medians
    and 90th percentiles; first a row's "all" line when its frames span several sequences (over one, it would
    repeat that sequence's line). Clean records only."""
    if "corruption" in records:
        records = records[records["corruption"].fillna("") == ""]
    lines = []
    for (combination, weights), group in records.groupby(["combination", "weights"], sort=False):
        parts = list(group.groupby(sequences(group), sort=True))
        whole = [(ALL, group)] if len(parts) > 1 else []
        for seq, part in whole + parts:
            lines.append([combination, weights, seq, *_sequence_cells(part, protocol)])
    return pd.DataFrame(lines, columns=SEQUENCE_ROW + SEQUENCE_COLUMNS)


def _sequence_cells(records: pd.DataFrame, protocol: Protocol) -> list:
    rte, rre = _errors(records)
    acc = 100.0 * float(((rte < protocol.acc_rte_m) & (rre < protocol.acc_rre_deg)).mean())
    return [len(records), round(acc, 2), *(percentile(e, q) for e in (rte, rre) for q in (50, 90))]
