"""One frame's record: the frame loaded under the protocol, run through the job's pipeline, scored.

Data flows one way: dataset -> SensorFrame -> protocol -> Frame -> pipeline -> PoseEstimate -> metrics -> record.
`load_frame` is where the protocol meets a loaded frame, for every executor: it corrupts it (under a corruption) and
moves it, so a corrupted record differs from a clean one only by its protocol card, which its cache key holds.
`compute_frame` is a pure function of (job, dataset, frame id, protocol), so frames can be farmed out to workers;
the store is the only shared state, and it is written one whole file per frame (`worker.store_result`).

Export, then evaluate: beside each record the store keeps what the frame's solver consumed (`runs.upstream`), keyed
by everything before the solver. A frame whose record is missing but whose upstream is stored (a new solver, a
RANSAC setting) is re-solved from it (`resolve_frame`): no dataset file is read and no extractor, encoder or matcher
runs, yet the record is the one a whole run gives, since the solver sees the same inputs.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..corruptions.base import CorruptionError
from ..data.base import Dataset
from ..errors import I2PBenchError
from ..scoring.installed import active, record_values
from ..scoring.metrics import Metric, Scored
from ..scoring.pose import pose_errors
from ..scoring.protocol import Protocol
from ..stages.components import STAGE_ORDER
from ..stages.pipeline import FrameOutcome
from ..types import Frame, PoseEstimate
from .environment import threads
from .jobs import Job, labels, upstream_key
from .store import ResultsStore
from .upstream import StoredUpstream

WHOLE, SOLVER = "pipeline", "solver"  # the two ways to compute a frame, each warmed up before its first timed frame


@dataclass(frozen=True)
class FrameContext:
    """What each frame of one combination is computed under: the prepared combination, the dataset, the protocol
    and the metrics recorded per frame (those of the run's registry)."""

    job: Job
    dataset: Dataset
    protocol: Protocol
    metrics: tuple[Metric, ...]


@dataclass
class Computed:
    """A frame's record, and its upstream when that is new (to store beside the record)."""

    record: dict[str, Any]
    upstream: StoredUpstream | None = None


def compute(
    ctx: FrameContext,
    frame_id: str,
    store: ResultsStore | None,
    warm: set[str],
    warmup: int = 1,
    reuse_upstream: bool = True,
) -> Computed:
    """The frame's record: re-solved from its stored upstream when the store has it and the solver can run alone,
    else from the whole pipeline. The first frame each way is preceded by `warmup` untimed runs (`warm` remembers).
    The upstream key is computed here once, for the look-up and the record alike."""
    job = ctx.job
    stored, read, key = None, 0.0, upstream_key(ctx.dataset, frame_id, job, ctx.protocol)
    if store is not None and reuse_upstream and job.pipeline.resolvable:
        start = time.perf_counter()
        stored = store.get_upstream(key, StoredUpstream.decode)
        read = time.perf_counter() - start
    if stored is None:
        if WHOLE not in warm and warmup:
            warm_up(ctx, frame_id, warmup)
        warm |= {WHOLE, SOLVER}
        return compute_frame(ctx, frame_id, key)
    if SOLVER not in warm:
        for _ in range(warmup):
            job.pipeline.resolve(stored.solver_frame(), stored.upstream)
        warm.add(SOLVER)
    return resolve_frame(ctx, frame_id, stored, key, read)


def warm_up(ctx: FrameContext, frame_id: str, times: int) -> None:
    """Untimed runs so one-off costs (lazy imports, allocator growth, JIT) stay out of latency figures."""
    try:
        frame = load_frame(ctx.dataset, frame_id, ctx.protocol)
    except I2PBenchError:
        return
    for _ in range(times):
        ctx.job.pipeline.run(frame)


def run_frame(
    job: Job, dataset: Dataset, frame_id: str, protocol: Protocol, metrics: tuple[Metric, ...] | None = None
) -> dict[str, Any]:
    """The record of one frame run through the whole pipeline (`compute_frame` without the upstream); `metrics`
    default: the installed ones."""
    return compute_frame(FrameContext(job, dataset, protocol, metrics or active()), frame_id).record


def load_frame(dataset: Dataset, frame_id: str, protocol: Protocol) -> Frame:
    """The registration problem of one frame under the protocol (its corruption included): the only place a run
    turns a dataset's frame into what the stages see."""
    return protocol.apply(dataset.load(frame_id))


def compute_frame(ctx: FrameContext, frame_id: str, up_key: str | None = None) -> Computed:
    """Load, run and score one frame; a dataset error becomes a failed record naming the file, while a failing
    corruption stops the run (a failed row would blame the method for the benchmark's fault). `up_key` is the frame's
    `upstream_key`, computed by the caller once per frame; None computes it here."""
    start = time.perf_counter()
    try:
        frame = load_frame(ctx.dataset, frame_id, ctx.protocol)
    except CorruptionError:
        raise
    except I2PBenchError as exc:
        outcome = FrameOutcome(
            PoseEstimate.failed(str(exc)), {}, error=str(exc), failed_component=f"dataset {ctx.dataset.name!r}"
        )
        elapsed = time.perf_counter() - start
        return Computed(_record(ctx, frame_id, outcome, None, elapsed, elapsed))
    loaded = time.perf_counter()
    outcome = ctx.job.pipeline.run(frame)
    record = _record(ctx, frame_id, outcome, frame, loaded - start, time.perf_counter() - start)
    upstream = StoredUpstream.of(frame, outcome)
    if upstream is not None:
        record["upstream_key"] = up_key or upstream_key(ctx.dataset, frame_id, ctx.job, ctx.protocol)
    return Computed(record, upstream)


def resolve_frame(
    ctx: FrameContext, frame_id: str, stored: StoredUpstream, up_key: str, read_s: float = 0.0
) -> Computed:
    """Run the solver alone on a frame's stored upstream and score it; the record is a whole run's, but
    `stages_run` says "solver", `t_load_s` is the upstream's read and the upstream stages' times are the stored ones
    (so `t_total_s` still estimates a whole frame's latency). `up_key` is the key `stored` was read under."""
    start = time.perf_counter()
    frame = stored.solver_frame()
    outcome = ctx.job.pipeline.resolve(frame, stored.upstream)
    ran = ",".join(outcome.timings)
    timings = {kind: t for kind, t in stored.timings.items() if not math.isnan(t)}  # NaN: that stage did not run
    outcome = dataclasses.replace(outcome, timings={**timings, **outcome.timings})
    wall = read_s + time.perf_counter() - start
    record = _record(ctx, frame_id, outcome, frame, read_s, wall)
    record.update(stages_run=ran, upstream_key=up_key)
    return Computed(record)


def _record(
    ctx: FrameContext, frame_id: str, outcome: FrameOutcome, frame: Frame | None, load: float, wall: float
) -> dict[str, Any]:
    job, dataset, protocol = ctx.job, ctx.dataset, ctx.protocol
    T_pred, T_gt = outcome.estimate.T, (frame.T_gt if frame is not None else None)
    errors = pose_errors(T_pred, T_gt) if T_gt is not None else pose_errors(None, np.eye(4))
    return {
        "dataset": dataset.name,
        "split": dataset.split,
        "frame_id": frame_id,
        "sequence": _sequence(dataset, frame_id),  # its KITTI sequence or drive, or nuScenes scene
        **labels(job),
        **{kind: job.combination.name(kind) for kind in STAGE_ORDER},
        "weights": job.weights,
        "weights_trained_on": job.pipeline.weights_meta.get("trained_on", ""),
        "protocol": protocol.identity(),
        "corruption": protocol.corruption,  # "" when clean
        "severity": protocol.severity,  # 0 when clean
        "status": "ok" if T_pred is not None else "failed",
        "error": outcome.error,
        "failed_component": outcome.failed_component,
        **record_values(Scored(frame, outcome, errors), ctx.metrics),  # every registered per-frame metric
        "model_size_mb": job.pipeline.model_size_mb(),
        "threads": threads(),
        "device": job.device,
        "t_total_s": sum(outcome.timings.values()),
        "t_load_s": load,
        "wall_s": wall,
        "T_pred": (T_pred.ravel().tolist() if T_pred is not None else None),
        "T_gt": (T_gt.ravel().tolist() if T_gt is not None else None),
        "stages_run": ",".join(outcome.timings),  # the stages this record's computation ran (and timed)
        "upstream_key": "",  # the stored upstream the solver consumed, once stored
        **{f"t_{kind}_s": outcome.timings.get(kind, np.nan) for kind in STAGE_ORDER},
    }


def _sequence(dataset: Dataset, frame_id: str) -> str:
    """The frame's sequence, "" when the dataset cannot tell (a frame that failed to load may not be in its tables)."""
    try:
        return dataset.sequence_of(frame_id)
    except I2PBenchError:
        return ""
