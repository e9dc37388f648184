"""The best and worst frame of each top combination, drawn from the stored poses (no pipeline re-run).

A report must still come out when the data has moved or gone: every failure to reload becomes a note for the page,
never an exception.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pandas as pd
from tqdm import tqdm

from ..errors import I2PBenchError
from ..registry.build import default_registry
from ..scoring.protocol import Protocol
from . import overlay
from .curves import rows
from .rundir import RunDir, best_and_worst, open_dataset, pose, reload_frame, resolved

JPEG_QUALITY = 85  # overlays are photographs with dots: JPEG keeps the page a few MB where PNG would be tens


@dataclass(frozen=True)
class Example:
    title: str  # e.g. "worst frame of lsd > ... : 00/000002"
    errors: str  # the stored errors, e.g. "RTE 0.03 m, RRE 0.09°" or "failed: ..."
    jpeg: bytes


def pick(run: RunDir, board: pd.DataFrame, n_rows: int) -> list[tuple[str, str, pd.Series]]:
    """[(kind, row label, record)]: best and worst frame of each of the first `n_rows` leaderboard rows."""
    order = list(zip(board["combination"], board["weights"], strict=True))[:n_rows]
    return [
        (kind, label, record)
        for label, group in rows(run.records, order)
        for kind, record in best_and_worst(group, run.protocol)
    ]


def render_examples(
    run: RunDir, board: pd.DataFrame, n_rows: int, data_root: str | None = None, quiet: bool = True
) -> tuple[list[Example], list[str]]:
    """(examples, notes) for the first `n_rows` leaderboard rows; notes say which could not be drawn and why."""
    picks = pick(run, board, n_rows)
    if not picks:
        return [], []
    registry = default_registry()
    try:
        dataset = open_dataset(registry, run.dataset, data_root)
    except I2PBenchError as exc:
        return [], [f"overlays left out: cannot open the run's dataset ({exc}); pass --data-root"]
    examples, notes = [], []
    for kind, label, record in tqdm(picks, disable=quiet, unit="overlay"):
        try:
            examples.append(_example(dataset, resolved(registry, run.protocol), kind, label, record))
        except I2PBenchError as exc:
            notes.append(f"{kind} frame of {label} ({record['frame_id']}) not drawn: {exc}")
    return examples, notes


def _example(dataset, protocol: Protocol, kind: str, label: str, record: pd.Series) -> Example:
    frame = reload_frame(dataset, protocol, record)
    panels = overlay.pose_panels(frame, pose(record, "T_pred"), failure=str(record.get("error", "")))
    title = f"{kind} frame of {label}: {record['frame_id']}"
    return Example(title, stored_errors(record), jpeg(overlay.compose(panels)))


def stored_errors(record: pd.Series) -> str:
    if record["status"] != "ok":
        return f"failed: {record.get('error') or 'no pose'}"
    rre = overlay.rre_text(record["rre_deg"], record.get("geodesic_deg", np.nan), "°")
    return f"RTE {record['rte_m']:.2f} m, {rre}"


def jpeg(image: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise I2PBenchError("could not encode an overlay as JPEG")
    return data.tobytes()
