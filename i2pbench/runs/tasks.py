"""What the driver hands a worker and what comes back: the types every executor and worker share.

The driver plans the work as tasks of (combination, chunk of frames not stored yet), each frame carrying its cache
key; a worker receives the `Work` (pipelines with their weights) once and sends back one `Result` per frame.
"""

from __future__ import annotations

import typing
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..data.base import Dataset
from ..scoring.installed import active
from ..scoring.metrics import Metric
from ..scoring.protocol import Protocol
from .jobs import Job
from .store import ResultsStore
from .upstream import StoredUpstream

Progress = Callable[[int], None]


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
    overwrite: bool = False  # recompute stored upstreams too
    # the metrics recorded per frame: the run's registry's (default: the installed ones); pickled by name
    metrics: tuple[Metric, ...] = field(default_factory=active)


Deliver = Callable[[Sequence[Result]], None]


class Executor(typing.Protocol):
    """Runs tasks on workers, handing each finished frame (or chunk) to `deliver` in the driver."""

    @property
    def workers(self) -> int: ...

    def start(self, work: Work, store: ResultsStore) -> None:
        """Start the workers with `work`; `store` is for executors whose workers write results themselves."""

    def run(self, tasks: Sequence[Task], deliver: Deliver) -> None: ...

    def close(self) -> None: ...
