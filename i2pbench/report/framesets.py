"""Which frames each leaderboard row ran on, so the report never ranks rows scored on different frames together.

A runs directory gathers every invocation's records: EdgeRegNet run on 40 frames yesterday and the classic
baselines on 4 today give rows whose Acc. are shares of different frames. The report puts rows on the same frames
in one table, one table per frame set, and adds a table of every row scored on the frames all rows share.
"""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from ..boards import leaderboard as lb
from ..scoring.protocol import Protocol
from .curves import ROW


@dataclass(frozen=True)
class FrameSet:
    """Leaderboard rows scored on exactly `frames`, in the leaderboard's order."""

    frames: tuple[str, ...]  # sorted frame ids
    board: pd.DataFrame


def row_frames(records: pd.DataFrame) -> dict[tuple[str, str], tuple[str, ...]]:
    """(combination, weights) -> the sorted frame ids its records hold."""
    return {key: tuple(sorted(set(group["frame_id"]))) for key, group in records.groupby(ROW, sort=False)}


def split(board: pd.DataFrame, records: pd.DataFrame, protocol: Protocol) -> list[FrameSet]:
    """One table per frame set, the set of the board's first row first; each is built from its own rows' records,
    so what a board says of a row against the row above (its paired tests) is said within the table."""
    frames = row_frames(records)
    keys = [frames[(c, w)] for c, w in zip(board["combination"], board["weights"], strict=True)]
    sets = list(dict.fromkeys(keys))
    if len(sets) == 1:
        return [FrameSet(sets[0], board)]
    of_record = [frames[key] for key in zip(records["combination"], records["weights"], strict=True)]
    return [FrameSet(s, lb.build(records[[k == s for k in of_record]], protocol)) for s in sets]


def shared_board(records: pd.DataFrame, sets: list[FrameSet], protocol: Protocol) -> FrameSet | None:
    """Every row rescored on the frames all rows ran (None when they share none)."""
    common = set.intersection(*(set(s.frames) for s in sets))
    if not common:
        return None
    return FrameSet(tuple(sorted(common)), lb.build(records[records["frame_id"].isin(common)], protocol))


def describe(frames: tuple[str, ...]) -> str:
    """'40 frames: 00/000000 … 00/000039' (every id when there are at most four)."""
    shown = ", ".join(frames) if len(frames) <= 4 else f"{frames[0]} … {frames[-1]}"
    return f"{len(frames)} frame{'s' * (len(frames) != 1)}: {shown}"
