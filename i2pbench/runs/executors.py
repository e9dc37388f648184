"""Run a grid's frames on several workers: a local process pool here, a Ray cluster in `ray_executor`.

The driver plans the work as tasks of (combination, chunk of frames not stored yet), each frame carrying its cache
key. Every worker receives the prepared jobs (pipelines with their weights) once, when it starts, pins its own thread
counts so that N workers on N cores do not oversubscribe them, and warms each pipeline up before its first frame.
`compute_frame` is pure, so a frame gives the same record whichever worker runs it and the leaderboard equals a
serial run's up to latency. Local workers re-solve frames whose upstream the store holds, as a serial run does; Ray
workers, which do not read the store, run frames whole and hand their upstreams back for the driver to store.

Who writes the store: local workers write each finished frame themselves (same machine; per-frame files written
atomically, so a killed run keeps every finished frame, as a serial run does); Ray workers hand records back to the
driver, which writes them, so a cluster needs no shared filesystem for results.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import typing
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field, replace
from typing import Any

import pandas as pd

from ..data.base import Dataset
from ..errors import I2PBenchError
from ..lifeline import exit_with_parent
from ..pipeline import Combination
from ..plugins import Registry
from ..protocol import Protocol
from .environment import fix_threads
from .runner import Job, Progress, compute, frame_key, labels, prepare, save
from .store import ResultsStore
from .upstream import StoredUpstream

DEFAULT_CHUNK = 8  # frames per task: few enough to balance a small grid, enough to amortise a task's overhead
THREAD_ENV = (
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
)


@dataclass(frozen=True)
class Task:
    """Frames of one combination to compute, with the cache key of each (planned by the driver)."""

    job: int  # index into Work.jobs
    frame_ids: tuple[str, ...]
    keys: tuple[str, ...]


@dataclass(frozen=True)
class Result:
    """One computed frame; `stored` says the worker already wrote it to the store."""

    job: int
    frame_id: str
    key: str
    record: dict[str, Any]
    stored: bool
    upstream: StoredUpstream | None = None  # for the driver to store, when the worker did not


@dataclass
class Work:
    """What every worker needs, shipped once per worker."""

    jobs: list[Job]
    dataset: Dataset
    protocol: Protocol
    invocation: str = ""
    warmup: int = 1
    store_root: str | None = None  # set: workers write each finished frame there themselves
    overwrite: bool = False  # recompute stored upstreams too


Deliver = Callable[[Sequence[Result]], None]


class Executor(typing.Protocol):
    """Runs tasks on workers, handing each finished frame (or chunk) to `deliver` in the driver."""

    @property
    def workers(self) -> int: ...

    def start(self, work: Work, store: ResultsStore) -> None:
        """Start the workers with `work`; `store` is for executors whose workers write results themselves."""

    def run(self, tasks: Sequence[Task], deliver: Deliver) -> None: ...

    def close(self) -> None: ...


def pin_threads(threads: int) -> int:
    """Fix this process's thread counts: env for libraries that start later, `fix_threads` for those loaded."""
    for name in THREAD_ENV:
        os.environ[name] = str(threads)
    return fix_threads(threads)


class Worker:
    """A worker's state: the jobs it received once, where they run, and which ones are warmed up."""

    def __init__(self, work: Work, threads: int, device: str | None = None) -> None:
        pin_threads(threads)
        if device:
            for job in work.jobs:
                job.pipeline.to(device)
                job.device = device
        self.work = work
        self.store = ResultsStore(work.store_root) if work.store_root else None
        self.warm: dict[int, set[str]] = {}

    def run(self, task: Task) -> Iterator[Result]:
        """Compute the task's frames one by one (re-solving those whose upstream the store holds, when this worker
        reads the store), warming the job up before its first frame in this worker."""
        w, job = self.work, self.work.jobs[task.job]
        warm = self.warm.setdefault(task.job, set())
        for frame_id, key in zip(task.frame_ids, task.keys, strict=True):
            computed = compute(job, w.dataset, frame_id, w.protocol, self.store, warm, w.warmup, not w.overwrite)
            record = {**computed.record, "invocation": w.invocation}
            if self.store is not None:
                save(self.store, key, record, computed.upstream)
                yield Result(task.job, frame_id, key, record, True)
            else:
                yield Result(task.job, frame_id, key, record, False, computed.upstream)


@dataclass
class Plan:
    """The grid's cache keys, the records found in the store, and the frames still to compute per job."""

    keys: dict[tuple[int, str], str]
    records: dict[tuple[int, str], dict[str, Any]]
    missing: dict[int, list[str]] = field(default_factory=dict)

    @property
    def to_compute(self) -> int:
        return sum(len(frames) for frames in self.missing.values())

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
    result = Plan({}, {})
    for j, job in enumerate(jobs):
        for frame_id in frame_ids:
            key = result.keys[j, frame_id] = frame_key(dataset, frame_id, job, protocol)
            record = None if overwrite else store.get(key)
            if record is None:
                result.missing.setdefault(j, []).append(frame_id)
            else:
                result.records[j, frame_id] = record
    return result


class Collector:
    """The driver's side of delivery: writes what workers did not, once per key, and counts progress."""

    def __init__(self, plan: Plan, store: ResultsStore, progress: Progress | None) -> None:
        self.plan, self.store, self.progress = plan, store, progress
        self.computed: set[tuple[int, str]] = set()

    def __call__(self, results: Sequence[Result]) -> None:
        fresh = [r for r in results if (r.job, r.frame_id) not in self.computed]  # a replayed frame is dropped
        for r in fresh:
            if not r.stored:
                save(self.store, r.key, r.record, r.upstream)
            self.plan.records[r.job, r.frame_id] = r.record
            self.computed.add((r.job, r.frame_id))
        if self.progress and fresh:
            self.progress(len(fresh))


def run_grid(
    registry: Registry,
    combinations: Sequence[Combination],
    dataset: Dataset,
    protocol: Protocol,
    store: ResultsStore,
    executor: Executor,
    *,
    weights: str = "auto",
    frame_ids: Sequence[str] | None = None,
    overwrite: bool = False,
    progress: Progress | None = None,
    invocation: str = "",
    chunk_size: int = DEFAULT_CHUNK,
) -> pd.DataFrame:
    """`runner.run_grid` on an executor's workers; the same records, in the same order, as a serial run.

    Pipelines are prepared on the CPU (so an incompatible combination is refused before any worker starts, and
    weights pickle without a GPU); each worker moves them to its own device.
    """
    jobs = prepare(registry, combinations, weights, "cpu", dataset.name)
    frame_ids = list(frame_ids if frame_ids is not None else dataset.frame_ids())
    work_plan = plan(jobs, dataset, frame_ids, protocol, store, overwrite)
    if progress and work_plan.records:
        progress(len(work_plan.records))
    if work_plan.to_compute:
        work = Work(jobs, dataset, protocol, invocation, overwrite=overwrite)
        run_plan(work_plan, work, store, executor, progress, chunk_size)
    return _frame(jobs, frame_ids, work_plan)


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
        executor.run(work_plan.tasks(executor.workers, chunk_size), Collector(work_plan, store, progress))
    finally:
        executor.close()
    lost = [(j, f) for j, frames in work_plan.missing.items() for f in frames if (j, f) not in work_plan.records]
    if lost:
        raise I2PBenchError(
            f"{len(lost)} frame(s) came back from no worker, e.g. {work.jobs[lost[0][0]].label} frame {lost[0][1]}"
        )


def _frame(jobs: Sequence[Job], frame_ids: Sequence[str], work_plan: Plan) -> pd.DataFrame:
    """Records in the serial run's order (job by job, frames in order), labels spelled as the serial run does."""
    rows = [{**work_plan.records[j, frame_id], **labels(job)} for j, job in enumerate(jobs) for frame_id in frame_ids]
    return pd.DataFrame(rows)


_WORKER: Worker | None = None  # a pool process's state, built once by its initializer


def _init_pool_worker(work: Work, threads: int, device: str | None) -> None:
    global _WORKER
    exit_with_parent()  # else a killed driver leaves its workers blocked on the task queue, weights in memory
    _WORKER = Worker(work, threads, device)


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
        work = replace(work, store_root=str(store.root))
        self._pool = ProcessPoolExecutor(
            self._workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_pool_worker,
            initargs=(work, self.threads, self.device),
        )

    def run(self, tasks: Sequence[Task], deliver: Deliver) -> None:
        """Deliver each chunk as it finishes; a dead worker process ends the run (finished frames stay stored)."""
        assert self._pool is not None, "start() first"
        pending: set[Future[list[Result]]] = {self._pool.submit(_run_pool_task, task) for task in tasks}
        try:
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    deliver(future.result())
        except BrokenProcessPool as exc:
            raise I2PBenchError(
                "a worker process died (killed, or out of memory); the frames it finished are stored, "
                "so running the same command again resumes"
            ) from exc

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


EXECUTORS = ("local", "ray")


def make_executor(
    kind: str = "local",
    workers: int | None = None,
    threads: int = 1,
    address: str | None = None,
    device: str | None = None,
) -> Executor | None:
    """The executor `i2pbench run` asked for, or None to run serially in this process (one local worker).

    Ray workers choose their own device (cuda where the cluster gives them a GPU), so `device` is for local ones.
    """
    if kind == "ray":
        from .ray_executor import RayExecutor

        return RayExecutor(address, workers, threads)
    if kind != "local":
        raise I2PBenchError(f"unknown executor {kind!r}; choose one of {', '.join(EXECUTORS)}")
    if address:
        raise I2PBenchError("--address names a Ray cluster: use it with --executor ray")
    return LocalExecutor(workers, threads, device) if workers and workers > 1 else None
