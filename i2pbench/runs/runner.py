"""Run combinations over a dataset split in this process, into the results store: the serial entry point.

A serial run is the one-worker in-process executor (`executors.InProcessExecutor`) under the driver that runs a
process pool or a Ray cluster too (`executors.run_grid` without an executor), so a frame is looked up, computed and
stored one way whichever runs it. A frame's record is made in `runs.frames` and its cache key in `runs.jobs`; the
names callers use to run frames by hand are re-exported here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ..data.base import Dataset
from ..protocol import Protocol
from ..scoring.metrics import true_matches
from .executors import InProcessExecutor, run_grid, run_work
from .frames import run_frame
from .jobs import Job, frame_key, prepare
from .store import ResultsStore
from .tasks import Progress, Work

__all__ = ["frame_key", "prepare", "run_frame", "run_grid", "run_job", "true_matches"]


def run_job(
    job: Job,
    dataset: Dataset,
    frame_ids: Sequence[str],
    protocol: Protocol,
    store: ResultsStore,
    *,
    overwrite: bool = False,
    warmup: int = 1,
    progress: Progress | None = None,
    invocation: str = "",
) -> list[dict[str, Any]]:
    """One prepared combination over frames in this process, where it was prepared; one record per frame.

    Stored frames are reused (and those whose upstream is stored re-solved); the warm-up runs just before the first
    frame actually computed, so a fully cached job costs no pipeline run at all and a re-solved one warms up its
    solver only.
    """
    work = Work([job], dataset, protocol, invocation, warmup, overwrite)
    return run_work(work, frame_ids, store, InProcessExecutor(), progress)
