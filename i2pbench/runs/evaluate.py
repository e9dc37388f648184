"""Metrics and the leaderboard recomputed from a runs directory alone: no dataset file is read, no stage runs.

The records of one invocation's grid (its combinations, frames and protocol, as its `invocations/<id>.json` file
lists them) are read back, their pose errors recomputed from the stored T_pred and T_gt, and the leaderboard built
under the run's protocol card, or under other success and filter thresholds, with every registered metric
(`scoring.metrics`): one a plugin adds is aggregated from the per-frame values its records stored.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .. import __version__
from ..boards import leaderboard
from ..errors import I2PBenchError
from ..scoring import installed as installed_metrics
from ..scoring.installed import read_back
from ..scoring.metrics import Scored
from ..scoring.pose import FAILED, pose_errors
from ..scoring.protocol import Protocol
from .invocation import history, record_file, written_by
from .store import ResultsStore

LAST, ALL = "last", "all"


@dataclasses.dataclass
class Evaluation:
    """A leaderboard recomputed from the store, what it was computed under, and from which records."""

    board: pd.DataFrame
    protocol: Protocol
    records: pd.DataFrame
    expected: int | None  # frames x combinations of the chosen invocation (None: every record)


def evaluate(run_dir: str | Path, invocation: str = LAST, **thresholds: float | None) -> Evaluation:
    """The leaderboard of `invocation`'s grid (or of ALL records) from the store; `thresholds` override the protocol
    card's fields (acc_rre_deg, acc_rte_m, filter_rre_deg, filter_rte_m; None keeps the card's)."""
    root = Path(run_dir)
    if not root.exists():
        raise I2PBenchError(
            f"{root} does not exist (give a folder `i2pbench run` wrote, such as runs/<dataset>-<split>)"
        )
    if not root.is_dir():
        raise I2PBenchError(f"{root} is a file, not a folder `i2pbench run` wrote (such as runs/<dataset>-<split>)")
    if not (root / "frames").is_dir():
        raise I2PBenchError(f"{root}: no per-frame results here (expected a folder `i2pbench run` wrote, such as "
                            "runs/<dataset>-<split>)")  # fmt: skip
    runs, records = history(root), ResultsStore(root, read_only=True).load()  # reading changes nothing
    if records.empty:
        raise I2PBenchError(f"{root}: the store holds no per-frame records")
    expected = None
    if invocation == ALL:
        _refuse_repeats(records, root)
        card = _single_card(records, runs, root)
    else:
        meta = _invocation(runs, invocation, root)
        with readable(root, meta):
            records, card = _grid(records, meta), meta["protocol"]
            expected = len(meta["frames"]) * len(meta["combinations"])
            read_back(card)
        if records.empty:
            raise I2PBenchError(f"{root}: none of invocation {meta['id']}'s frames is in the store")
    protocol = read_back(card).with_thresholds(**thresholds)
    records = rescore(records)
    return Evaluation(leaderboard.build(records, protocol), protocol, records, expected)


@contextlib.contextmanager
def readable(root: Path, meta: dict[str, Any]) -> Iterator[None]:
    """an invocation record of another layout (written by another version: a key missing, a protocol field this
    version does not know) is one error naming its file and the version that wrote it."""
    try:
        yield
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise I2PBenchError(
            f"{record_file(root, meta)}: written by {written_by(meta)}, which this i2pbench ({__version__}) cannot "
            f"read ({type(exc).__name__}: {exc}); evaluate it with that version, or rerun into a new --runs-dir"
        ) from None


def rescore(records: pd.DataFrame) -> pd.DataFrame:
    """The records with the registered metrics that read only the pose errors (rte_m, rre_deg, geodesic_deg)
    computed again from T_pred and T_gt, as a run scores them; other per-frame metrics are read as stored."""
    errors = [
        pose_errors(_matrix(pred), gt) if (gt := _matrix(truth)) is not None else FAILED
        for pred, truth in zip(records["T_pred"], records["T_gt"], strict=True)
    ]
    posed = [m for m in installed_metrics.active() if m.from_poses and m.frame is not None]
    return records.assign(**{m.name: [m.frame(Scored(None, None, e)) for e in errors] for m in posed})


def _matrix(values: Any) -> np.ndarray | None:
    if values is None or (np.ndim(values) == 0 and pd.isna(values)):
        return None
    return np.asarray(values, np.float64).reshape(4, 4)


def _invocation(runs: list[dict[str, Any]], wanted: str, root: Path) -> dict[str, Any]:
    """The chosen invocation's metadata: the last one, or the one whose id starts with `wanted`."""
    if not runs:
        raise I2PBenchError(f"{root}: no readable invocations/ files, so no grid to evaluate; pass --invocation all")
    if wanted == LAST:
        return runs[-1]
    found = [meta for meta in runs if str(meta.get("id", "")).startswith(wanted)]
    if len(found) != 1:
        ids = ", ".join(str(meta.get("id")) for meta in runs)
        raise I2PBenchError(f"--invocation {wanted!r} names {'no' if not found else 'more than one'} run; ids: {ids}")
    return found[0]


def _grid(records: pd.DataFrame, meta: dict[str, Any]) -> pd.DataFrame:
    """The records of an invocation's grid, in the run's order (combination by combination, frames in order), so
    ties in the leaderboard's sort fall as they did in the run."""
    keys = [_combination_key(describe) for describe in meta["combinations"]]
    frames = list(meta["frames"])
    protocol = Protocol.from_card(meta["protocol"]).identity()
    data = meta.get("dataset", {})
    chosen = (
        records["combination_key"].isin(keys)
        & records["frame_id"].isin(frames)
        & (records["protocol"] == protocol)
        & (records["dataset"] == data.get("dataset", records["dataset"]))
        & (records["split"] == data.get("split", records["split"]))
    )
    if meta.get("rows"):  # a finished run names its rows' weights: other weights' records of these stages are not its
        chosen &= records["weights"].isin({row["weights"] for row in meta["rows"]})
    order = records["combination_key"].map({key: i for i, key in enumerate(keys)}) * len(frames)
    order += records["frame_id"].map({frame: i for i, frame in enumerate(frames)})
    grid = records[chosen].assign(_order=order[chosen]).sort_values("_order", kind="stable")
    return _own_first(grid, meta.get("id")).drop(columns="_order")


def _own_first(grid: pd.DataFrame, invocation: str | None) -> pd.DataFrame:
    """one record per frame of a row: where the store holds several (a run over other data shared the store: split
    files with one `name:`), the invocation's own, else the latest."""
    if "invocation" not in grid:
        return grid
    own = (grid["invocation"] == invocation).astype(int)
    ranked = grid.assign(_own=own, _when=grid["invocation"].fillna("").astype(str))
    ranked = ranked.sort_values(["_order", "_own", "_when"], ascending=[True, False, False], kind="stable")
    row = [c for c in ("frame_id", "combination_key", "weights", "protocol") if c in grid]
    return ranked.drop_duplicates(subset=row).drop(columns=["_own", "_when"])


def _combination_key(describe: dict[str, dict[str, Any]]) -> str:
    """`Combination.key()` of a combination an invocation describes, without importing the pipeline (and torch)."""
    return hashlib.sha256(json.dumps(describe, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _refuse_repeats(records: pd.DataFrame, root: Path) -> None:
    """refuse to pool a store where one frame of one row is recorded more than once: runs over other data shared it
    (split files of one `name:` write to one store), and pooled they would count the frame twice."""
    row = [c for c in ("dataset", "split", "frame_id", "combination", "weights", "protocol") if c in records]
    repeated = records[records.duplicated(subset=row, keep=False)]
    if repeated.empty:
        return
    first = repeated.iloc[0]
    by = sorted({str(i) for i in repeated.get("invocation", pd.Series(dtype=str)).dropna()})
    runs = f" ({', '.join(by)})" if by else ""
    raise I2PBenchError(
        f"{root}: {repeated[row].drop_duplicates().shape[0]} frame(s) of a row are recorded more than once (e.g. "
        f"frame {first['frame_id']} of {first['combination']}), by runs over other data sharing this store (split "
        f"files with one name:){runs}; pooled, they would count twice. Evaluate "
        "one run's grid with --invocation ID"
    )


def _single_card(records: pd.DataFrame, runs: list[dict[str, Any]], root: Path) -> dict[str, Any]:
    """The protocol card shared by all the records (from the invocation that recorded it); refused when they mix."""
    identities = sorted(records["protocol"].unique())
    if len(identities) != 1:
        raise I2PBenchError(f"{root}: the records span {len(identities)} protocols ({', '.join(identities)}); "
                            "evaluate one invocation's grid with --invocation ID")  # fmt: skip
    cards = []
    for meta in runs:
        with readable(root, meta):
            cards += [meta["protocol"]] if Protocol.from_card(meta["protocol"]).identity() == identities[0] else []
    if not cards and Protocol().identity() != identities[0]:
        raise I2PBenchError(f"{root}: no invocation records protocol {identities[0]}'s card")
    return cards[0] if cards else Protocol().card()
