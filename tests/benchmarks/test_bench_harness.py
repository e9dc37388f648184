"""Latency of a reference-like pipeline on a real KITTI frame, and what the harness adds around the stages.

The harness overhead is the run's wall time minus the time inside the stages and the dataset's loading, as a share of
the wall time: the cache-key hashing, scoring, record building and the per-frame store write (target < 5%). Loading
is reported on its own: it belongs to the dataset, not the harness.

Time them with: pytest tests/benchmarks/test_bench_harness.py --benchmark-enable -s
(a plain pytest run executes each once, untimed, as a smoke test).
"""

from __future__ import annotations

import time

import pandas as pd
import pytest
from conftest import SAMPLE_DATA, sample

from i2pbench.registry.build import default_registry
from i2pbench.runs.executors import run_job
from i2pbench.runs.frames import run_frame
from i2pbench.runs.jobs import prepare
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination

KITTI = SAMPLE_DATA / "kitti_odometry"
REFERENCE = {"extractor2d": "lsd", "extractor3d": "depth+reflectance", "matcher": "oracle", "solver": "epnp-ransac"}


@pytest.fixture(scope="module")
def kitti():
    sample("kitti_odometry")
    from i2pbench.data.kitti import KittiOdometry

    return KittiOdometry("all", {"root": str(KITTI)})


@pytest.fixture(scope="module")
def job(kitti):
    (job,) = prepare(default_registry(), [Combination(REFERENCE)])
    job.pipeline.run(Protocol().apply(kitti.load(kitti.frame_ids()[0])))  # warm-up, as the runner does
    return job


def test_reference_pipeline_frame_latency(benchmark, kitti, job):
    frame = Protocol().apply(kitti.load(kitti.frame_ids()[0]))
    outcome = benchmark(job.pipeline.run, frame)
    assert outcome.estimate.ok
    benchmark.extra_info.update({f"{kind}_ms": 1e3 * t for kind, t in outcome.timings.items()})


def test_harness_overhead(benchmark, kitti, job, tmp_path):
    runs = iter(range(1000))

    def run():
        store = ResultsStore(tmp_path / str(next(runs)))
        start = time.perf_counter()
        records = run_job(job, kitti, kitti.frame_ids(), Protocol(), store, warmup=0)
        return time.perf_counter() - start, pd.DataFrame(records)

    wall, records = benchmark.pedantic(run, rounds=3, iterations=1)
    stages, load = records["t_total_s"].sum(), records["t_load_s"].sum()
    overhead = (wall - stages - load) / wall
    benchmark.extra_info.update(overhead_pct=100 * overhead, load_pct=100 * load / wall, stages_pct=100 * stages / wall)
    print(f"\nharness overhead {100 * overhead:.1f}% of {wall:.3f} s; loading {100 * load / wall:.1f}%")
    # the share is reported, never asserted (speed is a benchmark's figure: on a shared machine torch's first import
    # alone took it from 29% to 76%); what is asserted is that the timed run did the work it claims
    assert list(records["frame_id"]) == kitti.frame_ids() and (records["status"] == "ok").all()
    assert stages > 0 and load > 0 and wall > stages + load


def test_store_write(benchmark, kitti, job, tmp_path):
    record = run_frame(job, kitti, kitti.frame_ids()[0], Protocol())
    store, keys = ResultsStore(tmp_path), iter(range(10**6))
    benchmark(lambda: store.put(f"k{next(keys)}", record))


def test_store_read(benchmark, kitti, job, tmp_path):
    store = ResultsStore(tmp_path)
    store.put("k", run_frame(job, kitti, kitti.frame_ids()[0], Protocol()))
    assert benchmark(store.get, "k")["frame_id"] == kitti.frame_ids()[0]
