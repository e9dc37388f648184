"""Run combinations over a dataset split, one frame at a time, into the results store.

Data flows one way: dataset -> SensorFrame -> protocol -> Frame -> pipeline -> PoseEstimate -> metrics -> record.
`load_frame` is where the protocol meets a loaded frame, for every executor: it corrupts it (under a corruption) and
moves it, so a corrupted record differs from a clean one only by its protocol card, which its cache key holds.
`compute_frame` is a pure function of (job, dataset, frame id, protocol), so frames can be farmed out to workers;
the store is the only shared state, and it is written one whole file per frame.

Export, then evaluate: beside each record the store keeps what the frame's solver consumed (`runs.upstream`), keyed
by everything before the solver. A frame whose record is missing but whose upstream is stored (a new solver, a
RANSAC setting) is re-solved from it (`resolve_frame`): no dataset file is read and no extractor, encoder or matcher
runs, yet the record is the one a whole run gives, since the solver sees the same inputs.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
import torch

from ..components import STAGE_ORDER
from ..correspondence import true_match_mask
from ..corruptions import CorruptionError
from ..data.base import Dataset
from ..errors import I2PBenchError
from ..metrics import pose_errors
from ..pipeline import Combination, FrameOutcome, Pipeline
from ..plugins import Registry
from ..protocol import Protocol
from ..types import Frame, PoseEstimate
from ..weights import apply_checkpoint, select_checkpoint
from .store import ResultsStore, versioned_key
from .upstream import FORMAT, StoredUpstream

Progress = Callable[[int], None]
UNTRAINED_SEED = 0
WHOLE, SOLVER = "pipeline", "solver"  # the two ways to compute a frame, each warmed up before its first timed frame


@dataclass
class Job:
    """One combination ready to run: its pipeline (weights loaded) and identity."""

    combination: Combination
    pipeline: Pipeline
    device: str = "cpu"  # where the learned stages run

    @property
    def weights(self) -> str:
        return self.pipeline.weights_identity

    @property
    def label(self) -> str:
        """The combination's stages, variant and config overrides, so rows that differ only in config stay apart."""
        return self.combination.display

    def stages(self) -> dict[str, dict[str, Any]]:
        """Each stage's name and full config (defaults merged): a changed default changes the cache key."""
        return {kind: {"name": c.name, "conf": c.conf} for kind, c in self.pipeline.stages.items()}


def prepare(
    registry: Registry,
    combinations: Sequence[Combination],
    weights: str = "auto",
    device: str = "cpu",
    dataset: str | None = None,
) -> list[Job]:
    """Build every pipeline before any frame runs, so an incompatible combination is refused up front; `dataset`
    (a name) lets `--weights auto` prefer shipped weights trained on it."""
    shipped = [path for path, _ in registry.weights]
    jobs = []
    for combination in combinations:
        pipeline = _build(registry, combination)
        checkpoint = select_checkpoint(pipeline, weights, shipped, dataset)
        if checkpoint is not None:
            apply_checkpoint(pipeline, checkpoint)
        jobs.append(Job(combination, pipeline.to(device).eval(), str(device)))
    return jobs


def _build(registry: Registry, combination: Combination) -> Pipeline:
    """Build with a fixed torch seed, so an `untrained` row means the same initial weights in every run."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(UNTRAINED_SEED)
        return Pipeline.build(registry, combination)


def frame_key(dataset: Dataset, frame_id: str, job: Job, protocol: Protocol) -> str:
    """What is computed, versioned by the state of the frame's files: a repaired scan is recomputed, not reused."""
    return versioned_key(_key_parts(dataset, frame_id, job, protocol), dataset.fingerprint(frame_id))


def upstream_key(dataset: Dataset, frame_id: str, job: Job, protocol: Protocol) -> str:
    """`frame_key` less the solver: what the solver consumes, shared by every solver of a sweep."""
    parts = _key_parts(dataset, frame_id, job, protocol)
    parts["stages"] = {kind: stage for kind, stage in parts["stages"].items() if kind != "solver"}
    return versioned_key({**parts, "upstream": FORMAT}, dataset.fingerprint(frame_id))


def _key_parts(dataset: Dataset, frame_id: str, job: Job, protocol: Protocol) -> dict[str, Any]:
    parts = {
        "data": dataset.identity(),
        "frame": frame_id,
        "stages": job.stages(),
        "weights": job.weights,
        "protocol": protocol.card(),
    }
    corruption = protocol.component()
    if corruption is not None:  # its level and class too: an edited table recomputes (clean keys are unchanged)
        parts["corruption"] = corruption.describe(protocol.severity)
    return parts


@dataclass
class Computed:
    """A frame's record, and its upstream when that is new (to store beside the record)."""

    record: dict[str, Any]
    upstream: StoredUpstream | None = None


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
    """Run one combination over frames, reusing those already stored (and re-solving those whose upstream is);
    returns one record per frame.

    The warm-up runs just before the first frame that is actually computed, so a fully cached job costs no
    pipeline run at all, and a re-solved one warms up its solver only.
    """
    records, warm = [], set[str]()
    for frame_id in frame_ids:
        key = frame_key(dataset, frame_id, job, protocol)
        record = None if overwrite else store.get(key)
        if record is None:
            computed = compute(job, dataset, frame_id, protocol, store, warm, warmup, reuse_upstream=not overwrite)
            record = {**computed.record, "invocation": invocation}
            save(store, key, record, computed.upstream)
        records.append({**record, **labels(job)})  # the key holds resolved configs: labels follow this spelling
        if progress:
            progress(1)
    return records


def compute(
    job: Job,
    dataset: Dataset,
    frame_id: str,
    protocol: Protocol,
    store: ResultsStore | None,
    warm: set[str],
    warmup: int = 1,
    reuse_upstream: bool = True,
) -> Computed:
    """The frame's record: re-solved from its stored upstream when the store has it and the solver can run alone,
    else from the whole pipeline. The first frame each way is preceded by `warmup` untimed runs (`warm` remembers)."""
    stored, read = None, 0.0
    if store is not None and reuse_upstream and job.pipeline.resolvable:
        start = time.perf_counter()
        stored = store.get_upstream(upstream_key(dataset, frame_id, job, protocol), StoredUpstream.decode)
        read = time.perf_counter() - start
    if stored is None:
        if WHOLE not in warm and warmup:
            warm_up(job, dataset, protocol, frame_id, warmup)
        warm |= {WHOLE, SOLVER}
        return compute_frame(job, dataset, frame_id, protocol)
    if SOLVER not in warm:
        for _ in range(warmup):
            job.pipeline.resolve(stored.solver_frame(), stored.upstream)
        warm.add(SOLVER)
    return resolve_frame(job, dataset, frame_id, protocol, stored, read)


def save(store: ResultsStore, key: str, record: dict[str, Any], upstream: StoredUpstream | None) -> None:
    """Store a computed frame: its upstream first, so a record on disk always has the upstream it names."""
    if upstream is not None:
        store.put_upstream(record["upstream_key"], upstream.encode())
    store.put(key, record)


def warm_up(job: Job, dataset: Dataset, protocol: Protocol, frame_id: str, times: int) -> None:
    """Untimed runs so one-off costs (lazy imports, allocator growth, JIT) stay out of latency figures."""
    try:
        frame = load_frame(dataset, frame_id, protocol)
    except I2PBenchError:
        return
    for _ in range(times):
        job.pipeline.run(frame)


def run_frame(job: Job, dataset: Dataset, frame_id: str, protocol: Protocol) -> dict[str, Any]:
    """The record of one frame run through the whole pipeline (`compute_frame` without the upstream)."""
    return compute_frame(job, dataset, frame_id, protocol).record


def load_frame(dataset: Dataset, frame_id: str, protocol: Protocol) -> Frame:
    """The registration problem of one frame under the protocol (its corruption included): the only place a run
    turns a dataset's frame into what the stages see."""
    return protocol.apply(dataset.load(frame_id))


def compute_frame(job: Job, dataset: Dataset, frame_id: str, protocol: Protocol) -> Computed:
    """Load, run and score one frame; a dataset error becomes a failed record naming the file, while a failing
    corruption stops the run (a failed row would blame the method for the benchmark's fault)."""
    start = time.perf_counter()
    try:
        frame = load_frame(dataset, frame_id, protocol)
    except CorruptionError:
        raise
    except I2PBenchError as exc:
        outcome = FrameOutcome(
            PoseEstimate.failed(str(exc)), {}, error=str(exc), failed_component=f"dataset {dataset.name!r}"
        )
        elapsed = time.perf_counter() - start
        return Computed(_record(job, dataset, frame_id, protocol, outcome, None, elapsed, elapsed))
    loaded = time.perf_counter()
    outcome = job.pipeline.run(frame)
    record = _record(job, dataset, frame_id, protocol, outcome, frame, loaded - start, time.perf_counter() - start)
    upstream = StoredUpstream.of(frame, outcome)
    record["upstream_key"] = upstream_key(dataset, frame_id, job, protocol) if upstream is not None else ""
    return Computed(record, upstream)


def resolve_frame(
    job: Job, dataset: Dataset, frame_id: str, protocol: Protocol, stored: StoredUpstream, read_s: float = 0.0
) -> Computed:
    """Run the solver alone on a frame's stored upstream and score it; the record is a whole run's, but
    `stages_run` says "solver", `t_load_s` is the upstream's read and the upstream stages' times are the stored ones
    (so `t_total_s` still estimates a whole frame's latency)."""
    start = time.perf_counter()
    frame = stored.solver_frame()
    outcome = job.pipeline.resolve(frame, stored.upstream)
    ran = ",".join(outcome.timings)
    timings = {kind: t for kind, t in stored.timings.items() if not math.isnan(t)}  # NaN: that stage did not run
    outcome = dataclasses.replace(outcome, timings={**timings, **outcome.timings})
    wall = read_s + time.perf_counter() - start
    record = _record(job, dataset, frame_id, protocol, outcome, frame, read_s, wall)
    record.update(stages_run=ran, upstream_key=upstream_key(dataset, frame_id, job, protocol))
    return Computed(record)


def labels(job: Job) -> dict[str, str]:
    return {"combination": job.label, "combination_key": job.combination.key()}


def _record(
    job: Job,
    dataset: Dataset,
    frame_id: str,
    protocol: Protocol,
    outcome: FrameOutcome,
    frame: Frame | None,
    load: float,
    wall: float,
) -> dict[str, Any]:
    T_pred, T_gt = outcome.estimate.T, (frame.T_gt if frame is not None else None)
    errors = pose_errors(T_pred, T_gt) if T_gt is not None else pose_errors(None, np.eye(4))
    record: dict[str, Any] = {
        "dataset": dataset.name,
        "split": dataset.split,
        "frame_id": frame_id,
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
        "rte_m": errors.rte_m,
        "rre_deg": errors.rre_deg,
        "geodesic_deg": errors.geodesic_deg,
        "n_kp2d": outcome.n_kp2d,
        "n_kp3d": outcome.n_kp3d,
        "n_matches": outcome.n_matches,
        "n_inliers": outcome.n_inliers,
        "n_true_matches": true_matches(frame, outcome),
        "model_size_mb": job.pipeline.model_size_mb(),
        "threads": torch.get_num_threads(),
        "device": job.device,
        "t_total_s": sum(outcome.timings.values()),
        "t_load_s": load,
        "wall_s": wall,
        "T_pred": (T_pred.ravel().tolist() if T_pred is not None else None),
        "T_gt": (T_gt.ravel().tolist() if T_gt is not None else None),
        "stages_run": ",".join(outcome.timings),  # the stages this record's computation ran (and timed)
        "upstream_key": "",  # the stored upstream the solver consumed, once stored
    }
    record.update({f"t_{kind}_s": outcome.timings.get(kind, np.nan) for kind in STAGE_ORDER})
    return record


def true_matches(frame: Frame | None, outcome: FrameOutcome) -> float:
    """How many of the matcher's pairs are true under T_gt (within eps_c); NaN when the matcher did not run."""
    if frame is None or frame.T_gt is None or outcome.matched_uv is None or outcome.matched_xyz is None:
        return float("nan")
    return float(true_match_mask(frame, outcome.matched_uv, outcome.matched_xyz).sum())


def run_grid(
    registry: Registry,
    combinations: Sequence[Combination],
    dataset: Dataset,
    protocol: Protocol,
    store: ResultsStore,
    *,
    weights: str = "auto",
    device: str = "cpu",
    frame_ids: Sequence[str] | None = None,
    overwrite: bool = False,
    progress: Progress | None = None,
    invocation: str = "",
) -> pd.DataFrame:
    """Run every combination over the split; returns this grid's per-frame records (cached ones included)."""
    jobs = prepare(registry, combinations, weights, device, dataset.name)
    frame_ids = list(frame_ids if frame_ids is not None else dataset.frame_ids())
    records: list[dict[str, Any]] = []
    for job in jobs:
        records += run_job(
            job, dataset, frame_ids, protocol, store, overwrite=overwrite, progress=progress, invocation=invocation
        )
    return pd.DataFrame(records)
