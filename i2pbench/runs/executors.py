"""Run a grid's frames on an executor's workers: in this process (serial), on a local process pool, or on a Ray
cluster (`ray_executor`). Every executor runs the same `worker.Worker`; only how tasks reach it differs.

The driver looks every frame up in the store first and plans the rest as tasks of (combination, chunk of frames),
each frame carrying its cache key; a frame whose key another frame of the grid already has (an equivalent spelling)
is computed once. `compute_frame` is pure, so a frame gives the same record whichever worker runs it and the
leaderboard equals a serial run's up to latency. Workers that read the store re-solve frames whose upstream it
holds; Ray workers, which do not read it, run frames whole and hand their upstreams back for the driver to store.

Who writes the store: in-process and local workers write each finished frame themselves (same machine; per-frame
files written atomically, so a killed run keeps every finished frame); Ray workers hand records back to the driver,
which writes them, so a cluster needs no shared filesystem for results. Both write through `worker.store_result`.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import sys
from collections.abc import Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any

import pandas as pd

from ..data.base import Dataset
from ..errors import I2PBenchError
from ..execution.interrupts import Interrupted, ignore_held_sigint, sigint_held
from ..execution.lifeline import exit_with_parent
from ..registry.catalog import Registry
from ..scoring.installed import active
from ..scoring.protocol import Protocol
from ..stages.pipeline import Combination
from .jobs import Job, frame_key, labels, prepare
from .store import ResultsStore
from .tasks import Deliver, Executor, Progress, Result, Task, Work
from .worker import Worker, store_result

DEFAULT_CHUNK = 8  # frames per task: few enough to balance a small grid, enough to amortise a task's overhead
Slot = tuple[int, str]  # (job index, frame id)


@dataclass
class Plan:
    """The grid's cache keys, the records found in the store, the frames still to compute per job, and the frames
    whose key another one of the grid has (computed once, as that frame)."""

    keys: dict[Slot, str]
    records: dict[Slot, dict[str, Any]]
    missing: dict[int, list[str]] = field(default_factory=dict)
    same: dict[Slot, Slot] = field(default_factory=dict)

    @property
    def to_compute(self) -> int:
        return sum(len(frames) for frames in self.missing.values())

    def record(self, job: int, frame_id: str) -> dict[str, Any]:
        return self.records[self.same.get((job, frame_id), (job, frame_id))]

    def row(self, jobs: Sequence[Job], job: int, frame_id: str) -> dict[str, Any]:
        """The frame's record under the job's own spelling: a record is stored under the labels of the spelling that
        computed it (`frames`), and its key, shared by equivalent spellings, may bring it back to another one."""
        return {**self.record(job, frame_id), **labels(jobs[job])}

    def tasks(self, workers: int, chunk_size: int = DEFAULT_CHUNK) -> list[Task]:
        """Chunks of at most `chunk_size` frames, smaller when a job has too few frames to keep every worker busy."""
        tasks = []
        for job, frames in self.missing.items():
            size = max(1, min(chunk_size, math.ceil(len(frames) / workers)))
            for i in range(0, len(frames), size):
                chunk = tuple(frames[i : i + size])
                tasks.append(Task(job, chunk, tuple(self.keys[job, f] for f in chunk)))
        return tasks


def plan(
    jobs: Sequence[Job],
    dataset: Dataset,
    frame_ids: Sequence[str],
    protocol: Protocol,
    store: ResultsStore,
    overwrite: bool = False,
) -> Plan:
    """Look every frame up in the store first: only frames not stored become tasks (all of them with overwrite)."""
    result, first = Plan({}, {}), dict[str, Slot]()
    for j, job in enumerate(jobs):
        for frame_id in dict.fromkeys(frame_ids):
            key = result.keys[j, frame_id] = frame_key(dataset, frame_id, job, protocol)
            record = None if overwrite or key in first else store.get(key)
            if key in first:
                result.same[j, frame_id] = first[key]
            elif record is None:
                first[key] = (j, frame_id)
                result.missing.setdefault(j, []).append(frame_id)
            else:
                result.records[j, frame_id] = record
    return result


class Collector:
    """The driver's side of delivery: writes what workers did not, once per key, and counts progress. A progress
    callable with a `describe(label)` method is also told the combination of the next frame to compute (in task
    order: the one running, for a serial run), so a bar can name it."""

    def __init__(self, plan: Plan, store: ResultsStore, progress: Progress | None, labels: Sequence[str] = ()) -> None:
        self.plan, self.store, self.progress = plan, store, progress
        self.computed: set[Slot] = set()
        self.labels, self.order, self.next = labels, [(j, f) for j, fs in plan.missing.items() for f in fs], 0
        self._describe()

    def _describe(self) -> None:
        describe = getattr(self.progress, "describe", None)
        while self.next < len(self.order) and self.order[self.next] in self.computed:
            self.next += 1
        if describe is not None and self.labels and self.next < len(self.order):
            describe(self.labels[self.order[self.next][0]])

    def __call__(self, results: Sequence[Result]) -> None:
        fresh = [r for r in results if (r.job, r.frame_id) not in self.computed]  # a replayed frame is dropped
        for r in fresh:
            if not r.stored:
                store_result(self.store, r)
            self.plan.records[r.job, r.frame_id] = r.record
            self.computed.add((r.job, r.frame_id))
        if self.progress and fresh:
            self.progress(len(fresh))
            self._describe()


def run_grid(
    registry: Registry,
    combinations: Sequence[Combination],
    dataset: Dataset,
    protocol: Protocol,
    store: ResultsStore,
    executor: Executor | None = None,
    *,
    weights: str = "auto",
    device: str = "cpu",
    frame_ids: Sequence[str] | None = None,
    overwrite: bool = False,
    progress: Progress | None = None,
    invocation: str = "",
    chunk_size: int = DEFAULT_CHUNK,
) -> pd.DataFrame:
    """Every combination over the split on the executor's workers, or serially in this process without one (its
    learned stages on `device`; an executor's workers choose their own); returns this grid's per-frame records
    (cached ones included), in the same order whichever runs them.

    Pipelines are prepared on the CPU (so an incompatible combination is refused before any worker starts, and
    weights pickle without a GPU); each worker moves them to its own device.
    """
    jobs = prepare(registry, combinations, weights, "cpu", dataset.name)
    frame_ids = list(frame_ids if frame_ids is not None else dataset.frame_ids())
    work = Work(jobs, dataset, protocol, invocation, overwrite=overwrite, metrics=active(registry))
    executor = executor if executor is not None else InProcessExecutor(device)
    return pd.DataFrame(run_work(work, frame_ids, store, executor, progress, chunk_size))


def run_work(
    work: Work,
    frame_ids: Sequence[str],
    store: ResultsStore,
    executor: Executor,
    progress: Progress | None = None,
    chunk_size: int = DEFAULT_CHUNK,
) -> list[dict[str, Any]]:
    """The work's records, job by job with frames in order: read from the store, else computed on the executor's
    workers (started only when something is to compute). Labels follow each job's spelling."""
    work_plan = plan(work.jobs, work.dataset, frame_ids, work.protocol, store, work.overwrite)
    if progress and work_plan.records:
        progress(len(work_plan.records))
    if work_plan.to_compute:
        try:
            run_plan(work_plan, work, store, executor, progress, chunk_size)
        except KeyboardInterrupt as exc:  # the user's Ctrl-C: the workers are stopped; say what finished
            finished = [(j, f) for j in range(len(work.jobs)) for f in frame_ids if _done(work_plan, j, f)]
            records = [work_plan.row(work.jobs, j, f) for j, f in finished]
            raise Interrupted(records) from exc
    if progress and work_plan.same:
        progress(len(work_plan.same))
    return [work_plan.row(work.jobs, j, f) for j in range(len(work.jobs)) for f in frame_ids]


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


def _done(work_plan: Plan, job: int, frame_id: str) -> bool:
    return work_plan.same.get((job, frame_id), (job, frame_id)) in work_plan.records


def run_plan(
    work_plan: Plan,
    work: Work,
    store: ResultsStore,
    executor: Executor,
    progress: Progress | None = None,
    chunk_size: int = DEFAULT_CHUNK,
) -> None:
    """Start the executor's workers, run the plan's tasks on them, and stop them."""
    executor.start(work, store)
    try:
        collector = Collector(work_plan, store, progress, [job.label for job in work.jobs])
        executor.run(work_plan.tasks(executor.workers, chunk_size), collector)
    finally:
        executor.close()
    lost = [(j, f) for j, frames in work_plan.missing.items() for f in frames if (j, f) not in work_plan.records]
    if lost:
        raise I2PBenchError(
            f"{len(lost)} frame(s) came back from no worker, e.g. {work.jobs[lost[0][0]].label} frame {lost[0][1]}"
        )


class InProcessExecutor:
    """Serial running: one worker in this process, writing each frame to the store and delivering it as it finishes.

    It keeps the process's thread counts (`i2pbench run --threads`); `device` moves the pipelines, None leaves them
    where they were prepared.
    """

    workers = 1

    def __init__(self, device: str | None = None) -> None:
        self.device = device
        self._worker: Worker | None = None

    def start(self, work: Work, store: ResultsStore) -> None:
        self._worker = Worker(work, store, device=self.device)

    def run(self, tasks: Sequence[Task], deliver: Deliver) -> None:
        assert self._worker is not None, "start() first"
        for task in tasks:
            for result in self._worker.run(task):
                deliver([result])

    def close(self) -> None:
        self._worker = None


_WORKER: Worker | None = None  # a pool process's worker, built once by its initializer


def _init_pool_worker(work: Work, store_root: str, threads: int, device: str | None) -> None:
    global _WORKER
    exit_with_parent()  # else a killed driver leaves its workers blocked on the task queue, weights in memory
    ignore_held_sigint()  # Ctrl-C is the driver's: it stops the run and terminates us
    _WORKER = Worker(work, ResultsStore(store_root), threads, device)


def _run_pool_task(task: Task) -> list[Result]:
    assert _WORKER is not None, "the pool's initializer did not run"
    return list(_WORKER.run(task))


class LocalExecutor:
    """A pool of worker processes on this machine, each writing its finished frames to the store.

    Processes start with "spawn": a fresh interpreter inherits no lock held by another thread at fork time (torch's
    and OpenCV's thread pools, the stage time limiter's worker) and no CUDA state.
    """

    def __init__(self, workers: int, threads: int = 1, device: str | None = None) -> None:
        if workers < 1:
            raise I2PBenchError(f"--workers must be at least 1, got {workers}")
        self._workers, self.threads, self.device = workers, threads, device
        self._pool: ProcessPoolExecutor | None = None

    @property
    def workers(self) -> int:
        return self._workers

    def start(self, work: Work, store: ResultsStore) -> None:
        self._pool = ProcessPoolExecutor(
            self._workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_pool_worker,
            initargs=(work, str(store.root), self.threads, self.device),
        )

    def run(self, tasks: Sequence[Task], deliver: Deliver) -> None:
        """Deliver each chunk as it finishes; a dead worker process ends the run (finished frames stay stored)."""
        assert self._pool is not None, "start() first"
        pending: set[Future[list[Result]]] = set()
        try:
            with sigint_held():  # the pool starts its processes on these submits
                pending = {self._pool.submit(_run_pool_task, task) for task in tasks}
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    deliver(future.result())
        except BrokenProcessPool as exc:
            raise I2PBenchError(
                "a worker process died (killed, or out of memory); the frames it finished are stored, "
                "so running the same command again resumes"
            ) from exc
        except KeyboardInterrupt:
            self._terminate()
            raise

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def _terminate(self) -> None:
        """Stop every worker now (shutdown would let each finish its chunk first): frames they finished are stored,
        a frame they were writing leaves a temp file the store sweeps when next opened."""
        pool, self._pool = self._pool, None
        if pool is None:
            return
        processes = list((getattr(pool, "_processes", None) or {}).values())  # no public way before Python 3.14
        for process in processes:
            process.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.join(timeout=10)


EXECUTORS = ("local", "ray")


def make_executor(
    kind: str = "local",
    workers: int | None = None,
    threads: int = 1,
    address: str | None = None,
    device: str | None = None,
) -> Executor | None:
    """The executor `i2pbench run` asked for, or None for one local worker (`run_grid` then runs in this process).

    Ray workers choose their own device (cuda where the cluster gives them a GPU), so `device` is for local ones.
    """
    if kind == "ray":
        from .ray_executor import RayExecutor

        return RayExecutor(address, workers, threads)
    if kind != "local":
        raise I2PBenchError(f"unknown executor {kind!r}; choose one of {', '.join(EXECUTORS)}")
    if address:
        raise I2PBenchError("--address names a Ray cluster: use it with --executor ray")
    workers = capped_workers(workers)
    return LocalExecutor(workers, threads, device) if workers and workers > 1 else None


def usable_cores() -> int:
    """the cores this process may run on (its affinity mask, e.g. a container's or taskset's share)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def capped_workers(workers: int | None) -> int | None:
    """local workers beyond the cores only contend (each holding its own copy of the weights), which inflates the
    latencies a board reports: at most one per usable core, said on stderr when capped."""
    cap = usable_cores()
    if workers is None or workers <= cap:
        return workers
    print(f"i2pbench: note: --workers {workers} capped at {cap}, the cores this process may use", file=sys.stderr)
    return cap
