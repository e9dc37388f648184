"""Process isolation for untrusted plugins: a frame's stages run in a child process, killed when time runs out.

The stage time limit (`i2pbench.execution.timeout`) abandons a thread, which cannot stop a stage holding the GIL in C,
nor survive one that segfaults or calls os._exit. With I2PBENCH_ISOLATE=process (`i2pbench run --isolate process`) every
process that runs frames keeps one spawned child, and `isolated` wraps each pipeline built to run frames so that its
frames go there (the pipeline itself knows nothing of it). The child receives the pipeline (pickled, once, and again
whenever its learned weights change), then one frame at a time; as each stage starts it says which, sending the records
of the stages finished since (each stage's output crosses once), and at the end the last records and the failure, if
any, from which the parent builds the frame's trace. A frame that overruns is failed in the running stage's name,
keeping the records received, and the child is SIGKILLed; a child that crashes fails its frame the same way; the next
frame starts a fresh child. The price: a second copy of the pipeline, a few seconds to start each child, and pickling
every frame and stage output.
"""

from __future__ import annotations

import itertools
import multiprocessing
import os
import pickle
import signal
import threading
import time
import uuid
from collections.abc import Sequence
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any

from ..errors import I2PBenchError, IsolationError
from ..stages.pipeline import Pipeline
from ..stages.trace import FrameOutcome, StageRecord
from .interrupts import ignore_held_sigint, sigint_held
from .lifeline import exit_with_parent
from .timeout import StageTimeout

if TYPE_CHECKING:
    import torch

    from ..types import Frame

ENV_VAR = "I2PBENCH_ISOLATE"
MODES = ("thread", "process")
START_LIMIT_S = 120.0  # the least time a child gets to start and load a pipeline (it imports torch and the plugins)
KILLED = "its process was killed"


def isolation_from_env(default: str = "thread") -> str:
    """The mode set by I2PBENCH_ISOLATE ("thread" or "process"), else `default`."""
    value = os.environ.get(ENV_VAR, "").strip().lower() or default
    if value not in MODES:
        raise I2PBenchError(f"{ENV_VAR}={value!r}: expected one of {', '.join(MODES)}")
    return value


def isolated(pipeline: Pipeline, mode: str = "env") -> Pipeline:
    """`pipeline` itself under mode "thread"; under "process" the same stages as a pipeline whose frames run in this
    process's child. "env" reads the mode from I2PBENCH_ISOLATE."""
    if (isolation_from_env() if mode == "env" else mode) != "process":
        return pipeline
    wrapped = IsolatedPipeline(pipeline.combination, pipeline.stages, pipeline.limiter.timeout_s)
    wrapped.weights_identity, wrapped.weights_meta = pipeline.weights_identity, pipeline.weights_meta
    return wrapped


class IsolatedPipeline(Pipeline):
    """A pipeline whose frames run in this process's child, which a time limit kills."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.token = uuid.uuid4().hex  # which pipeline the child holds; pickled copies keep it, in their own process

    @property
    def resolvable(self) -> bool:
        return False  # the child is handed whole frames only

    def run(self, frame: Frame) -> FrameOutcome:
        timeout_s = self.limiter.timeout_s
        with _LOCK:  # one conversation with the child at a time, whichever thread runs frames
            child = _child()
            try:
                child.load(self, self.token, timeout_s)
            except (IsolationError, StageTimeout) as exc:
                return self.failed(exc, "")
            return child.run(self, frame, timeout_s)


_CHILD: _Child | None = None
_LOCK = threading.Lock()


def _child() -> _Child:
    """This process's child, started afresh when there is none, it died or was killed, or this is a forked copy."""
    global _CHILD
    if _CHILD is None or not _CHILD.usable():
        _CHILD = _Child()
    return _CHILD


class _Child:
    def __init__(self) -> None:
        context = multiprocessing.get_context("spawn")  # a fresh interpreter: no lock or CUDA state from this one
        self.conn, theirs = context.Pipe()
        self.process = context.Process(target=_serve, args=(theirs,), name="i2pbench-isolated", daemon=True)
        with sigint_held():  # a Ctrl-C during its start-up is not a traceback of its own
            self.process.start()
        theirs.close()  # so that the child's death reads as end-of-file here
        self.owner = os.getpid()
        self.holds: tuple[str, Any] | None = None  # (token, fingerprint) of the pipeline it has

    def usable(self) -> bool:
        return self.owner == os.getpid() and self.process.is_alive()

    def load(self, pipeline: Pipeline, token: str, timeout_s: float | None) -> None:
        """Hand the child the pipeline, unless it already holds it as it is now."""
        state = (token, fingerprint(pipeline))
        if self.holds == state:
            return
        try:
            payload = pickle.dumps(pipeline)
        except Exception as exc:
            raise IsolationError(f"the pipeline does not pickle ({type(exc).__name__}: {exc})") from None
        from ..runs.environment import threads

        self._send(("load", payload, threads()))
        limit = None if timeout_s is None else max(START_LIMIT_S, timeout_s)
        reply = self._receive(time.monotonic(), limit, f"{KILLED} while starting")
        if reply[0] == "error":
            raise IsolationError(f"its process could not load the pipeline: {reply[1]}")
        self.holds = state

    def run(self, pipeline: Pipeline, frame: Frame, timeout_s: float | None) -> FrameOutcome:
        """The frame's trace from the child; a timeout or the child's death fails it in the running stage's name."""
        stage, records = "", []
        start = time.monotonic()
        try:
            self._send(("frame", frame))
            while (message := self._receive(start, timeout_s))[0] == "stage":
                _, stage, finished = message
                records += finished
        except (IsolationError, StageTimeout) as exc:
            return pipeline.failed(exc, stage, records)
        _, finished, failure = message
        return FrameOutcome.of(records + finished, failure)

    def _send(self, message: tuple[Any, ...]) -> None:
        try:
            self.conn.send_bytes(pickle.dumps(message))
        except OSError:
            raise IsolationError(self._kill()) from None

    def _receive(self, start: float, limit: float | None, fate: str = KILLED) -> tuple[Any, ...]:
        """The child's next message; the child is killed when `limit` seconds from `start` pass (StageTimeout)."""
        try:
            if self.conn.poll(None if limit is None else max(0.0, start + limit - time.monotonic())):
                return pickle.loads(self.conn.recv_bytes())
        except (EOFError, OSError):
            raise IsolationError(self._kill()) from None
        except BaseException:  # a Ctrl-C while waiting: the frame is given up, and the child with it
            self._kill()
            raise
        self._kill()
        assert limit is not None  # poll(None) returns only once there is something to read
        raise StageTimeout(limit, fate)

    def _kill(self) -> str:
        """SIGKILL the child (if still alive) and say how it ended."""
        self.process.kill()
        self.process.join(5)
        self.conn.close()
        code = self.process.exitcode
        how = f"signal {signal.Signals(-code).name}" if code is not None and code < 0 else f"exit code {code}"
        return f"its process died ({how})"


def fingerprint(pipeline: Pipeline) -> tuple[Any, ...]:
    """What changes when learned weights do (an optimiser step, a checkpoint, a move): storage, version, mode."""
    return tuple(
        (kind, module.training, tuple((t.data_ptr(), t._version) for t in _tensors(module)))
        for kind, module in pipeline.learned_modules().items()
    )


def _tensors(module: torch.nn.Module) -> itertools.chain[torch.Tensor]:
    return itertools.chain(module.parameters(), module.buffers())


def _serve(conn: Connection) -> None:
    """The child's loop: take a pipeline, then frames, until the parent closes the pipe or dies."""
    ignore_held_sigint()  # Ctrl-C is the parent's: it stops the run and kills this process
    exit_with_parent()
    pipeline = None
    while True:
        try:
            kind, *body = pickle.loads(conn.recv_bytes())
        except EOFError:
            return
        if kind == "load":
            pipeline, reply = _load(*body)
            conn.send_bytes(pickle.dumps(reply))
        else:
            assert pipeline is not None, "a frame came before any pipeline"
            reporter = _Reporter(conn)
            reporter.done(pipeline, pipeline.run_here(body[0], listener=reporter.stage))


def _load(payload: bytes, threads: int) -> tuple[Pipeline | None, tuple[str, ...]]:
    from ..runs.environment import fix_threads

    try:
        pipeline = pickle.loads(payload)
    except BaseException as exc:  # a plugin module that fails to import here, or exits while importing
        return None, ("error", f"{type(exc).__name__}: {exc}")
    fix_threads(threads)  # the parent's thread count, so latency is comparable with an in-process run
    return pipeline, ("loaded",)


class _Reporter:
    """The child's side of one frame: each stage's record crosses to the parent once, with the next stage's start
    or with the frame's end."""

    def __init__(self, conn: Connection) -> None:
        self.conn, self.sent = conn, 0

    def stage(self, progress: Any) -> None:
        """A stage starts: its kind, and the records finished since the last message (held back when they do not
        pickle, for `done` to report: the stage starting is not at fault)."""
        new = self._new(progress.records)
        try:
            payload = pickle.dumps(("stage", progress.running, new))
        except Exception:
            payload = pickle.dumps(("stage", progress.running, []))
        else:
            self.sent += len(new)
        self.conn.send_bytes(payload)

    def done(self, pipeline: Pipeline, outcome: FrameOutcome) -> None:
        """The frame ends: the records not yet sent and the failure, or a failure saying what does not pickle."""
        try:
            payload = pickle.dumps(("done", self._new(outcome.records), outcome.failure))
        except Exception as exc:  # a stage's output that does not pickle
            payload = pickle.dumps(("done", [], pipeline.failed(exc, "").failure))
        self.conn.send_bytes(payload)

    def _new(self, records: Sequence[StageRecord]) -> list[StageRecord]:
        return list(records[self.sent :])
