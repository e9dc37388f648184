"""The one worker code every executor runs: in this process (serial), in a pool process, or in a Ray actor.

A worker receives the `Work` once, pins its thread counts (when asked, so that N workers on N cores do not
oversubscribe them), moves the pipelines to its device, and then, task by task, computes each frame: re-solved from
its stored upstream when it reads the store and the store has one, else run whole, the job warmed up before its
first frame in this worker. A worker that reads the store also writes each finished frame to it; one that does not
(a Ray actor) hands the record and its upstream back for the driver to store. Either way `store_result` writes it:
the store's one writer of frames.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterator

from .environment import fix_threads
from .frames import FrameContext, compute
from .store import ResultsStore
from .tasks import Result, Task, Work

THREAD_ENV = (
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
)


def pin_threads(threads: int) -> int:
    """Fix this process's thread counts: env for libraries that start later, `fix_threads` for those loaded."""
    for name in THREAD_ENV:
        os.environ[name] = str(threads)
    return fix_threads(threads)


def store_result(store: ResultsStore, result: Result) -> Result:
    """Write a computed frame to the store, its upstream first (so a record on disk always has the upstream it
    names); the result comes back marked stored, without the upstream it no longer needs to carry."""
    if result.upstream is not None:
        store.put_upstream(result.record["upstream_key"], result.upstream.encode())
    store.put(result.key, result.record)
    return dataclasses.replace(result, stored=True, upstream=None)


class Worker:
    """A worker's state: the jobs it received once, the store it writes (if any), and which jobs are warmed up.

    `threads` None leaves the process's thread counts as they are (the serial run's `--threads`); `device` None
    leaves the pipelines where they were prepared.
    """

    def __init__(
        self, work: Work, store: ResultsStore | None = None, threads: int | None = None, device: str | None = None
    ) -> None:
        if threads is not None:
            pin_threads(threads)
        if device:
            for job in work.jobs:
                job.to(device)
        self.work, self.store = work, store
        self.warm: dict[int, set[str]] = {}

    def run(self, task: Task) -> Iterator[Result]:
        """Compute the task's frames one by one, each delivered as soon as it is done (and stored, when this
        worker writes the store)."""
        w, job = self.work, self.work.jobs[task.job]
        warm = self.warm.setdefault(task.job, set())
        ctx = FrameContext(job, w.dataset, w.protocol, w.metrics)
        for frame_id, key in zip(task.frame_ids, task.keys, strict=True):
            computed = compute(ctx, frame_id, self.store, warm, w.warmup, not w.overwrite)
            record = {**computed.record, "invocation": w.invocation}
            result = Result(task.job, frame_id, key, record, False, computed.upstream)
            yield result if self.store is None else store_result(self.store, result)
