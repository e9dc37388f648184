"""Run combinations over a dataset split, one frame at a time, into the results store.

Data flows one way: dataset -> SensorFrame -> protocol -> Frame -> pipeline -> PoseEstimate -> metrics -> record.
`run_frame` is a pure function of (job, dataset, frame id, protocol), so frames can be farmed out to workers; the
store is the only shared state, and it is written one whole file per frame.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
import torch

from ..components import STAGE_ORDER
from ..correspondence import true_match_mask
from ..data.base import Dataset
from ..errors import I2PBenchError
from ..metrics import pose_errors
from ..pipeline import Combination, FrameOutcome, Pipeline
from ..plugins import Registry
from ..protocol import Protocol
from ..types import Frame, PoseEstimate
from ..weights import apply_checkpoint, select_checkpoint
from .store import ResultsStore, versioned_key

Progress = Callable[[int], None]
UNTRAINED_SEED = 0


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
    parts = {
        "data": dataset.identity(),
        "frame": frame_id,
        "stages": job.stages(),
        "weights": job.weights,
        "protocol": protocol.card(),
    }
    return versioned_key(parts, dataset.fingerprint(frame_id))


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
    """Run one combination over frames, reusing those already stored; returns one record per frame.

    The warm-up runs just before the first frame that is actually computed, so a fully cached job costs no
    pipeline run at all.
    """
    records, warm = [], warmup == 0
    for frame_id in frame_ids:
        key = frame_key(dataset, frame_id, job, protocol)
        record = None if overwrite else store.get(key)
        if record is None:
            if not warm:
                warm_up(job, dataset, protocol, frame_id, warmup)
                warm = True
            record = {**run_frame(job, dataset, frame_id, protocol), "invocation": invocation}
            store.put(key, record)
        records.append({**record, **labels(job)})  # the key holds resolved configs: labels follow this spelling
        if progress:
            progress(1)
    return records


def warm_up(job: Job, dataset: Dataset, protocol: Protocol, frame_id: str, times: int) -> None:
    """Untimed runs so one-off costs (lazy imports, allocator growth, JIT) stay out of latency figures."""
    try:
        frame = protocol.apply(dataset.load(frame_id))
    except I2PBenchError:
        return
    for _ in range(times):
        job.pipeline.run(frame)


def run_frame(job: Job, dataset: Dataset, frame_id: str, protocol: Protocol) -> dict[str, Any]:
    """Load, run and score one frame; a dataset error becomes a failed record naming the file."""
    start = time.perf_counter()
    try:
        frame = protocol.apply(dataset.load(frame_id))
    except I2PBenchError as exc:
        outcome = FrameOutcome(
            PoseEstimate.failed(str(exc)), {}, error=str(exc), failed_component=f"dataset {dataset.name!r}"
        )
        elapsed = time.perf_counter() - start
        return _record(job, dataset, frame_id, protocol, outcome, None, elapsed, elapsed)
    loaded = time.perf_counter()
    outcome = job.pipeline.run(frame)
    return _record(job, dataset, frame_id, protocol, outcome, frame, loaded - start, time.perf_counter() - start)


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
