"""Frames for the commands that summarise a dataset (`diagnose`, `domain-gap`): a frame that cannot be loaded is
named on stderr with why, and skipped, so one broken file does not throw away the diagnosis of every other frame.

A benchmark run instead stores such a frame as a failure (it counts against Acc.); a summary of statistics has no
failure to count, so it leaves the frame out and says how many it left out.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator, Sequence
from typing import Any

from ..errors import DataError, I2PBenchError
from ..types import Frame


def loaded_frames(dataset: Any, frame_ids: Sequence[str], protocol: Any, command: str) -> Iterator[Frame]:
    """Each frame under `protocol`; one whose loading fails is warned about (naming it) and skipped, a count of
    those is noted at the end, and an error is raised when none could be loaded."""
    skipped = 0
    for frame_id in frame_ids:
        try:
            frame = protocol.apply(dataset.load(frame_id))
        except I2PBenchError as exc:
            skipped += 1
            print(f"i2pbench: warning: {command}: frame {frame_id} skipped: {exc}", file=sys.stderr)
            continue
        yield frame
    if skipped == len(frame_ids) and skipped:
        raise DataError(f"{command}: none of the {skipped} frames of {dataset.name!r} could be loaded (named above)")
    if skipped:
        print(f"i2pbench: note: {command}: {skipped} of {len(frame_ids)} frames skipped (named above)", file=sys.stderr)
