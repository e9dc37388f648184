"""A runs directory as a report sees it: its per-frame records, the protocol they used, and the way back to a frame.

Overlays are drawn from the stored poses (each record keeps T_pred and T_gt), so a report never re-runs a pipeline:
the frame itself is reloaded from the dataset identity the run recorded and moved by the recorded protocol, which
reproduces the exact registration problem (the protocol's transform depends only on seed, dataset and frame id).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..errors import DataError, I2PBenchError
from ..runs.evaluate import readable
from ..runs.invocation import history
from ..runs.store import ResultsStore
from ..scoring.installed import read_back
from ..scoring.protocol import Protocol
from ..types import Frame

RUN_META = "run.json"  # a run's metadata file, when the harness writes one beside invocations/


@dataclass
class RunDir:
    """Records of one protocol from a runs directory, with what is needed to reload their frames."""

    root: Path
    records: pd.DataFrame
    protocol: Protocol
    dataset: dict[str, Any]  # the dataset identity the run recorded ({} when unknown)
    meta: list[dict[str, Any]] = field(default_factory=list)  # run.json then every invocation, oldest first
    notes: list[str] = field(default_factory=list)  # what the report should tell the reader (dropped records, ...)


def load_run(root: str | Path) -> RunDir:
    """Read a runs directory (e.g. runs/kitti-all); refuses one without results."""
    root = Path(root)
    if not (root / "frames").is_dir():
        raise I2PBenchError(f"{root}: not a runs directory (no frames/ inside); pass e.g. runs/kitti-all")
    records = ResultsStore(root).load()
    if records.empty:
        raise I2PBenchError(f"{root}: no per-frame results in {root / 'frames'}")
    meta = _metadata(root)
    with readable(root, next((m for m in reversed(meta) if isinstance(m.get("protocol"), dict)), {})):
        protocol = _latest(meta, "protocol", Protocol(), read_back)
    records, notes = _one_protocol(records, protocol)
    return RunDir(root, records, protocol, _latest(meta, "dataset", {}, dict), meta, notes)


def _metadata(root: Path) -> list[dict[str, Any]]:
    """run.json (if any) first, then each invocation's file, so the latest invocation has the last word."""
    path = root / RUN_META
    first = [json.loads(path.read_text())] if path.is_file() else []
    return first + history(root)


def _latest(meta: list[dict[str, Any]], key: str, default: Any, make: Any) -> Any:
    values = [m[key] for m in meta if isinstance(m.get(key), dict)]
    return make(values[-1]) if values else default


def _one_protocol(records: pd.DataFrame, protocol: Protocol) -> tuple[pd.DataFrame, list[str]]:
    """Keep the records scored under `protocol`: Acc. and the curves mean nothing across two protocols."""
    if "protocol" not in records:
        return records, []
    kept = records[records["protocol"] == protocol.identity()]
    if kept.empty:
        return records, [f"no record carries the recorded protocol {protocol.identity()}; showing all records"]
    dropped = len(records) - len(kept)
    return kept.reset_index(drop=True), [f"{dropped} records of other protocols left out"] if dropped else []


def open_dataset(registry: Any, identity: dict[str, Any], data_root: str | None = None) -> Any:
    """The dataset split the run used, configured from its identity (keys it does not take as config are skipped)."""
    if not identity:
        raise DataError("the run recorded no dataset identity (no invocations/ or run.json)")
    cls = registry.dataset(identity["dataset"])
    conf = {k: v for k, v in identity.items() if k in cls.default_conf and _same_shape(cls.default_conf[k], v)}
    if data_root or not conf.get("root"):
        conf["root"] = data_root
    return cls(identity["split"], conf)


def _same_shape(default: Any, value: Any) -> bool:
    """Whether an identity value can stand as config (a synthetic set records a frame count where config nests)."""
    return not isinstance(default, dict) or isinstance(value, dict)


def frame_score(records: pd.DataFrame, protocol: Protocol) -> pd.Series:
    """Error in units of the protocol's success thresholds (RTE and RRE each divided by theirs): orders frames from
    best to worst with one number; failures are infinite."""
    rte, rre = records["rte_m"].astype(float), records["rre_deg"].astype(float)
    score = rte / protocol.acc_rte_m + rre / protocol.acc_rre_deg
    return score.where(records["status"] == "ok", np.inf).fillna(np.inf)


def best_and_worst(records: pd.DataFrame, protocol: Protocol) -> list[tuple[str, pd.Series]]:
    """[("best", record), ("worst", record)] of one combination's records (one entry when it has one frame)."""
    order = frame_score(records, protocol).sort_values(kind="stable").index
    picks = [("best", records.loc[order[0]])]
    return picks + ([("worst", records.loc[order[-1]])] if len(order) > 1 else [])


def pose(record: pd.Series, key: str) -> np.ndarray | None:
    """A stored 4 x 4 pose (records keep them as 16 floats, None for a failed solve)."""
    value = record.get(key)
    return None if value is None or len(value) != 16 else np.asarray(value, dtype=np.float64).reshape(4, 4)


def resolved(registry: Any, protocol: Protocol) -> Protocol:
    """`protocol` with its corruption's component, the registry's of that name: the run's card names it only."""
    if not protocol.corruption or protocol.corrupter is not None:
        return protocol
    return dataclasses.replace(protocol, corrupter=registry.corruption(protocol.corruption)())


def reload_frame(dataset: Any, protocol: Protocol, record: pd.Series) -> Frame:
    """The registration problem the record was scored on; refuses when the data no longer gives the stored T_gt."""
    frame = protocol.apply(dataset.load(record["frame_id"]))
    stored = pose(record, "T_gt")
    if stored is not None and not np.allclose(stored, frame.T_gt, atol=1e-6):
        raise DataError(f"frame {record['frame_id']}: the reloaded ground truth differs from the stored one")
    return frame
