"""The one worker code every executor runs: in this process (serial), in a pool process, or in a Ray actor.

A worker receives the `Work` once, pins its thread counts (when asked, so that N workers on N cores do not
oversubscribe them), moves the pipelines to its device, and then, task by task, computes each frame: re-solved from
its stored upstream when it reads the store and the store has one, else run whole, the job warmed up before its
first frame in this worker. A worker that reads the store also writes each finished frame to it; one that does not
(a Ray actor) hands the record and its upstream back for the driver to store.
"""

from __future__ import annotations

import os
from collections.abc import Iterator

from .environment import fix_threads
from .frames import compute, save
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
        for frame_id, key in zip(task.frame_ids, task.keys, strict=True):
            computed = compute(job, w.dataset, frame_id, w.protocol, self.store, warm, w.warmup, not w.overwrite)
            record = {**computed.record, "invocation": w.invocation}
            if self.store is None:
                yield Result(task.job, frame_id, key, record, False, computed.upstream)
                continue
            save(self.store, key, record, computed.upstream)
            yield Result(task.job, frame_id, key, record, True)
