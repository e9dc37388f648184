"""Run a grid's tasks on a Ray cluster (the optional extra `i2pbench[ray]`, imported only when used).

Workers are Ray actors, each built once from the work put into the object store once (`ray.put`): the weights travel
to each node once and are deserialised once per actor, never per task or frame. An actor asks for `num_gpus` when
the cluster has GPUs and its jobs have learned stages, else for CPUs only.

An actor streams one record per frame back to the driver, which writes it to the store as it arrives, so results
need no shared filesystem and a lost worker costs only its unfinished frames: Ray restarts the actor
(`max_restarts`) and the driver resubmits the chunk's frames that never came back. The driver does the retrying
rather than Ray's own task retry because the latter would rerun the whole chunk; it drops any frame it already has,
so a retry neither duplicates nor loses a result.
"""

from __future__ import annotations

import logging
import socket
import sys
import time
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from types import ModuleType
from typing import Any
from urllib.parse import urlsplit

from ..errors import I2PBenchError
from .store import ResultsStore
from .tasks import Deliver, Result, Task, Work
from .worker import Worker

CPU, GPU = "cpu", "gpu"


def import_ray() -> ModuleType:
    try:
        import ray
    except ImportError as exc:
        raise I2PBenchError(
            "--executor ray needs Ray: pip install 'i2pbench[ray]' (or pip install 'ray>=2.9')"
        ) from exc
    return ray


PROBE_TIMEOUT_S = 10.0  # to connect, and again to hear the handshake; a live cluster answers in milliseconds
H2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])  # + an empty SETTINGS frame
SETTINGS = 4  # the HTTP/2 frame type a gRPC server answers the preface with
DEFAULT_PORTS = {"ray": 10001, "": 6379}  # Ray client's port for ray://, else the GCS's
START_HINT = "start one with `ray start --head` and pass the address it prints (or ray://HOST:10001)"


def check_address(address: str | None, timeout_s: float = PROBE_TIMEOUT_S) -> None:
    """Refuse an address where no Ray cluster answers, before `ray.init` waits on it without end (it retries a dead
    or foreign address forever): a TCP connection, then the HTTP/2 handshake every Ray endpoint speaks (the GCS and
    the Ray client server are gRPC), each within `timeout_s`. None, "local" and "auto" are Ray's to resolve."""
    if address in (None, "", "local", "auto"):
        return
    host, port = _host_port(address)
    where = f"--address {address}"
    try:
        with socket.create_connection((host, port), timeout=timeout_s) as conn:
            conn.settimeout(timeout_s)
            conn.sendall(H2_PREFACE)
            head = _read(conn, 9)
    except TimeoutError:
        raise I2PBenchError(f"{where}: no Ray cluster answered within {timeout_s:g} s; {START_HINT}") from None
    except OSError as exc:
        raise I2PBenchError(f"{where}: no Ray cluster there ({exc.strerror or exc}); {START_HINT}") from None
    if len(head) < 9 or head[3] != SETTINGS:
        raise I2PBenchError(
            f"{where}: something listens there but does not answer as a Ray cluster (no gRPC handshake); {START_HINT}"
        )


def _host_port(address: str) -> tuple[str, int]:
    parts = urlsplit(address if "://" in address else f"//{address}")
    try:
        port = parts.port or DEFAULT_PORTS.get(parts.scheme)
    except ValueError:
        port = None
    if not parts.hostname or port is None:
        raise I2PBenchError(f"--address {address}: expected HOST:PORT or ray://HOST:PORT (or auto)")
    return parts.hostname, port


def _read(conn: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n and (chunk := conn.recv(n - len(data))):
        data += chunk
    return data


class RayWorker:
    """The actor's body: a `Worker` built on the first task, then streaming each frame's result once computed.

    Each call carries the work as a reference inside a list, which Ray passes on unresolved; only the first call
    fetches it. A constructor argument would do the same once, but Ray cannot restart an actor whose constructor
    took an object-store reference (ray-project/ray#53727), and says so on every run.
    """

    def __init__(self, threads: int, gpu: bool) -> None:
        self.threads, self.device = threads, "cuda" if gpu else "cpu"
        self.worker: Worker | None = None

    def run(self, work: list[Any], task: Task) -> Iterator[Result]:
        if self.worker is None:
            import ray

            self.worker = Worker(ray.get(work[0]), None, self.threads, self.device)  # the driver stores
        yield from self.worker.run(task)


MAX_WAITS = 120  # resubmissions to a restarting actor before it counts as lost
RESTART_WAIT_S = 0.25


@dataclass
class Attempt:
    """A chunk in flight on one actor: what has not come back yet, and how many times it was resubmitted."""

    actor: Any
    shape: str
    task: Task
    retries: int = 0
    waits: int = 0  # resubmissions since the loss to an actor Ray was still restarting (not new losses)


class RayExecutor:
    """Actors on a Ray cluster (`address`: "auto", "ray://host:10001", ...; None starts a local instance)."""

    def __init__(
        self,
        address: str | None = None,
        workers: int | None = None,
        threads: int = 1,
        gpus_per_worker: float = 1.0,
        max_retries: int = 3,
    ) -> None:
        check_address(address)  # first: needs no Ray, and an address nobody answers at would hang ray.init
        self.ray = import_ray()
        self.address, self.requested, self.threads = address, workers, threads
        self.gpus_per_worker, self.max_retries = gpus_per_worker, max_retries
        self._owns_ray = False
        self._work_ref: Any = None
        self._jobs_gpu: list[bool] = []
        self.actors: dict[str, list[Any]] = {}

    @property
    def workers(self) -> int:
        """Actors the cluster can hold at once (or as asked): the driver sizes its chunks by it."""
        return self.requested or max(1, self._capacity(CPU))

    def start(self, work: Work, store: ResultsStore) -> None:
        """Join (or start) Ray and put the work, weights included, into the object store once."""
        if not self.ray.is_initialized():
            cpus = self.requested * self.threads if self.address is None and self.requested else None
            try:
                self.ray.init(
                    address=self.address or "local",
                    num_cpus=cpus,
                    include_dashboard=False,
                    logging_level=logging.WARNING,
                )
            except (ConnectionError, RuntimeError, ValueError) as exc:  # e.g. auto with no cluster running here
                raise I2PBenchError(
                    f"--address {self.address or 'local'}: Ray could not start or join ({exc})"
                ) from None
            self._owns_ray = True
        gpus = self.ray.cluster_resources().get("GPU", 0) > 0
        self._jobs_gpu = [gpus and bool(job.pipeline.learned_modules()) for job in work.jobs]
        self._work_ref = self.ray.put(work)

    def run(self, tasks: Sequence[Task], deliver: Deliver) -> None:
        """Keep every actor busy with a chunk; deliver each frame as it streams back; resubmit what a lost actor
        never sent."""
        queues = {GPU: deque[Attempt](), CPU: deque[Attempt]()}  # GPU actors first: CPU ones get the CPUs left
        for task in tasks:
            queues[self.shape(task.job)].append(Attempt(None, self.shape(task.job), task))
        idle = {shape: deque(self._actors(shape, len(queue))) for shape, queue in queues.items() if queue}
        inflight: dict[Any, Attempt] = {}
        while inflight or any(queues.values()):
            self._dispatch(queues, idle, inflight)
            [ready], _ = self.ray.wait(list(inflight), num_returns=1)
            self._advance(ready, inflight, idle, queues, deliver)

    def close(self) -> None:
        for actor in (a for actors in self.actors.values() for a in actors):
            self.ray.kill(actor)
        self.actors = {}
        if self._owns_ray:
            self.ray.shutdown()
            self._owns_ray = False

    def shape(self, job: int) -> str:
        """GPU for a job with learned stages on a cluster with GPUs; CPU otherwise."""
        return GPU if self._jobs_gpu[job] else CPU

    def actor_options(self, shape: str) -> dict[str, Any]:
        """Resources an actor of this shape reserves, and how often Ray restarts it when its process is lost."""
        options: dict[str, Any] = {"num_cpus": self.threads, "max_restarts": self.max_retries, "max_task_retries": 0}
        if shape == GPU:
            options["num_gpus"] = self.gpus_per_worker
        return options

    def _dispatch(self, queues: dict[str, deque[Attempt]], idle: dict[str, deque], inflight: dict) -> None:
        for shape, queue in queues.items():
            while queue and idle.get(shape):
                attempt = queue.popleft()
                attempt.actor = idle[shape].popleft()
                inflight[attempt.actor.run.remote([self._work_ref], attempt.task)] = attempt

    def _advance(self, generator: Any, inflight: dict, idle: dict, queues: dict, deliver: Deliver) -> None:
        """Take the next frame from a ready stream; a finished stream frees its actor, a broken one is retried."""
        attempt = inflight[generator]
        try:
            result: Result = self.ray.get(next(generator))
        except StopIteration:
            del inflight[generator]
            self._free(attempt, idle, queues)
            return
        except (self.ray.exceptions.RayActorError, self.ray.exceptions.ObjectLostError) as exc:
            del inflight[generator]
            idle[attempt.shape].append(attempt.actor)  # Ray restarts it (max_restarts)
            queues[attempt.shape].appendleft(self._retry(attempt, exc))
            return
        deliver([result])
        attempt.task = _without(attempt.task, result.frame_id)
        attempt.waits = 0  # the actor answers again: a later failure is a new loss

    def _free(self, attempt: Attempt, idle: dict, queues: dict) -> None:
        """Back to the idle pool; but an actor with no work of its shape left while the other shape's work waits is
        killed, to hand its CPUs to actors of that shape that may be waiting for them."""
        others_wait = any(queue for shape, queue in queues.items() if shape != attempt.shape)
        if queues[attempt.shape] or not others_wait:
            idle[attempt.shape].append(attempt.actor)
            return
        self.ray.kill(attempt.actor)
        self.actors[attempt.shape].remove(attempt.actor)

    def _retry(self, attempt: Attempt, exc: Exception) -> Attempt:
        restarting = getattr(self.ray.exceptions, "ActorUnavailableError", None)
        is_restarting = restarting is not None and isinstance(exc, restarting)
        if is_restarting and 0 < attempt.waits < MAX_WAITS:
            time.sleep(RESTART_WAIT_S)  # still the same loss: Ray is restarting the actor, give it time
            return replace(attempt, actor=None, waits=attempt.waits + 1)
        if attempt.retries >= self.max_retries:
            raise I2PBenchError(
                f"a Ray worker was lost {attempt.retries + 1} times on frames {list(attempt.task.frame_ids)}; "
                f"finished frames are stored, so running the same command again resumes ({exc})"
            ) from exc
        lost = f"i2pbench: a Ray worker was lost ({type(exc).__name__}); resubmitting its unfinished frame(s)"
        print(f"{lost}: {list(attempt.task.frame_ids)}", file=sys.stderr)
        return replace(attempt, actor=None, retries=attempt.retries + 1, waits=int(is_restarting))

    def _actors(self, shape: str, tasks: int) -> list[Any]:
        """This shape's actors, created on first need: as many as asked, the cluster holds, and tasks can use."""
        if not self.actors.get(shape):
            n = max(1, min(self.requested or self._capacity(shape), self._capacity(shape) or 1, tasks))
            actor_class = self.ray.remote(RayWorker).options(**self.actor_options(shape))
            self.actors[shape] = [actor_class.remote(self.threads, shape == GPU) for _ in range(n)]
        return self.actors[shape]

    def _capacity(self, shape: str) -> int:
        resources = self.ray.cluster_resources() if self.ray.is_initialized() else {}
        if shape == GPU:
            return int(resources.get("GPU", 0) // self.gpus_per_worker)
        held_by_gpu_actors = len(self.actors.get(GPU, [])) * self.threads
        return int((resources.get("CPU", 0) - held_by_gpu_actors) // self.threads)


def _without(task: Task, frame_id: str) -> Task:
    """The task less one frame that came back, so a retry resubmits only what is still missing."""
    keep = [i for i, f in enumerate(task.frame_ids) if f != frame_id]
    return Task(task.job, tuple(task.frame_ids[i] for i in keep), tuple(task.keys[i] for i in keep))
