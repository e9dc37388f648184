"""Speed-up of local workers (and Ray actors) over one, and each executor's per-task overhead, on the real KITTI frames.

The workload is a classic grid (3 2D x 3 3D extractors x 2 solvers, oracle matcher: 18 combinations) over the six
frames in ../shared/data/kitti_odometry, 108 frames in all, CPU-bound. For each executor and worker count it times:

- start-up: from `start()` to the end of a first, cold pass over the grid (processes spawned, i2pbench imported,
  pipelines unpickled and warmed up: what one `i2pbench run` pays on top of the frames);
- steady: a second pass over the same tasks on the same, now warm, workers (records written again);
- per task: a batch of empty tasks, so the executor's own cost per task (submit, hand-off, result, delivery) shows
  without any frame work; the per-frame cost (one record streamed back and written) is in the steady pass;
- frame ms and busy %: the median time a worker spent on one frame (loading included), and the share of the
  workers' steady time spent on frames. A frame slower with 2 workers than with 1 while busy % stays high means
  the cores were shared with other processes, not lost to the executor.

Serial (in-process, one thread) is the baseline. Counts alternate (1, 2, 1, 2, ...) over `--repeat` rounds and the
medians are printed, so the load of a shared machine drifting during the run biases neither side. `--edgeregnet`
sizes the small EdgeRegNet (the default preset) instead: fewer frames/s, so one round over the six frames.
`--sleep-ms MS` replaces the 2D extractor by one that waits MS ms (6 copies of that combination): the cores are then
not the limit, so the speed-up shows how well the executor overlaps its workers even on a busy machine.

    .venv/bin/python benchmarks/scale_speedup.py [--workers 1 2] [--repeat 3] [--ray] [--edgeregnet | --sleep-ms 50]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from i2pbench.api import Extractor2D, Keypoints2D, hookimpl
from i2pbench.data.kitti import KittiOdometry
from i2pbench.registry.build import build_registry, default_registry
from i2pbench.registry.catalog import Registry
from i2pbench.runs.executors import Collector, Executor, LocalExecutor, Task, Work, plan, run_job
from i2pbench.runs.grid import expand
from i2pbench.runs.jobs import prepare
from i2pbench.runs.store import ResultsStore
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Combination

KITTI = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_odometry"
CLASSIC_BASE = {"matcher": "oracle"}
CLASSIC_GRID = {
    "extractor2d": ["lsd", "canny", "sobel"],
    "extractor3d": ["depth", "reflectance", "depth+reflectance"],
    "solver": ["epnp-ransac", "poselib"],
}
EMPTY_TASKS = 200
SLEEP_COPIES = 6


class Sleep(Extractor2D):
    """waits instead of computing, then gives four fixed keypoints."""

    name = "sleep"
    default_conf = {"ms": 50, "copy": 0}  # copy: tells apart otherwise identical combinations

    def __call__(self, frame):
        time.sleep(self.conf["ms"] / 1e3)
        return Keypoints2D(np.array([[100, 100], [200, 100], [100, 200], [200, 200]], np.float32))


class SleepPlugin:
    @hookimpl
    def register_extractors_2d(self, register) -> None:
        register(Sleep)


def workload(args: argparse.Namespace) -> tuple[Registry, list[Combination]]:
    if args.sleep_ms:
        if args.ray:
            _ship_this_script_to_ray()
        base = {"extractor2d": "sleep", "extractor3d": "random", "matcher": "oracle", "solver": "epnp-ransac"}
        confs = [{"extractor2d": {"ms": args.sleep_ms, "copy": i}} for i in range(SLEEP_COPIES)]
        return build_registry((SleepPlugin(),)), [Combination(base, conf) for conf in confs]
    registry = default_registry()
    if args.edgeregnet:
        return registry, expand(registry.preset("default").combinations, {})
    return registry, expand([CLASSIC_BASE], CLASSIC_GRID)


def _ship_this_script_to_ray() -> None:
    """Ray workers cannot import this script: its Sleep stage travels by value."""
    import ray

    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])


def serial(work: Work, frame_ids: list[str], root: Path) -> float:
    """The grid in this process on one thread, as `i2pbench run --threads 1` does it."""
    from i2pbench.runs.environment import fix_threads

    fix_threads(1)
    store, start = ResultsStore(root / f"serial-{time.monotonic_ns()}"), time.perf_counter()
    for job in work.jobs:
        run_job(job, work.dataset, frame_ids, work.protocol, store)
    return time.perf_counter() - start


def timed(fn: Callable[[], object]) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def measure(executor: Executor, work: Work, frame_ids: list[str], root: Path) -> dict[str, float]:
    """Start-up (start + cold pass), steady pass and per-task overhead of one executor."""
    store = ResultsStore(root / f"run-{time.monotonic_ns()}")
    work_plan = plan(work.jobs, work.dataset, frame_ids, work.protocol, store)
    start = time.perf_counter()
    executor.start(work, store)
    try:
        tasks = work_plan.tasks(executor.workers)
        executor.run(tasks, Collector(work_plan, store, None))
        cold = time.perf_counter() - start
        steady = timed(lambda: executor.run(tasks, Collector(work_plan, store, None)))
        empty = timed(lambda: executor.run([Task(0, (), ())] * EMPTY_TASKS, lambda results: None))
    finally:
        executor.close()
    frame_s = [r["wall_s"] for r in work_plan.records.values()]  # the steady pass's records replaced the cold ones
    return {
        "startup_s": cold - steady,
        "steady_s": steady,
        "frame_ms": 1e3 * statistics.median(frame_s),
        "busy_pct": 100 * sum(frame_s) / (steady * executor.workers),
        "task_ms": 1e3 * empty / EMPTY_TASKS,
        "tasks": len(tasks),
    }


def make(kind: str, workers: int, threads: int) -> Executor:
    if kind == "ray":
        from i2pbench.runs.ray_executor import RayExecutor

        return RayExecutor(None, workers, threads)
    return LocalExecutor(workers, threads)


def report(kind: str, results: dict[int, list[dict[str, float]]], frames: int, serial_s: float) -> None:
    base = statistics.median(r["steady_s"] for r in results[min(results)])
    print(f"\n{kind}: {frames} frames per pass; serial (1 thread, in-process) {serial_s:.2f} s")
    print("workers | steady s | frames/s | per worker | speed-up vs 1 | vs serial | frame ms | busy % | start-up s | "
          "task ms | tasks")  # fmt: skip
    for n, runs in sorted(results.items()):
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        fps = frames / med["steady_s"]
        print(
            f"{n:7d} | {med['steady_s']:8.2f} | {fps:8.2f} | {fps / n:10.2f} | {base / med['steady_s']:13.2f} | "
            f"{serial_s / med['steady_s']:9.2f} | {med['frame_ms']:8.1f} | {med['busy_pct']:6.1f} | "
            f"{med['startup_s']:10.2f} | {med['task_ms']:7.2f} | {med['tasks']:.0f}"
        )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--threads-per-worker", type=int, default=1)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--ray", action="store_true", help="also time Ray actors on a local Ray instance")
    p.add_argument("--edgeregnet", action="store_true", help="the small EdgeRegNet (default preset), not the grid")
    p.add_argument("--sleep-ms", type=float, help="a 2D extractor that waits this long, not the classic grid")
    args = p.parse_args()
    dataset = KittiOdometry("all", {"root": str(KITTI)})
    frame_ids = dataset.frame_ids()
    registry, combos = workload(args)
    work = Work(prepare(registry, combos), dataset, Protocol())
    frames = len(work.jobs) * len(frame_ids)
    print(f"cpus {os.cpu_count()}, load average before {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as tmp:
        serial_s = statistics.median(serial(work, frame_ids, Path(tmp)) for _ in range(args.repeat))
        for kind in ["local", "ray"] if args.ray else ["local"]:
            results: dict[int, list[dict[str, float]]] = {n: [] for n in args.workers}
            for _ in range(args.repeat):
                for n in args.workers:
                    results[n].append(measure(make(kind, n, args.threads_per_worker), work, frame_ids, Path(tmp)))
            report(kind, results, frames, serial_s)
    print(f"\nload average after {os.getloadavg()}")


if __name__ == "__main__":
    main()
