"""Training throughput: the old loop (one frame per step, data work and point grouping in the loop) against the
batched loop (DataLoader workers, per-frame grouping cache, padded batches), in one process, on synthetic/train.

For each size (`cpu`: the default preset; `paper`: edgeregnet-full) it prints frames/s of both loops and their ratio,
where a new step's time goes (data wait, host-to-device copy, forward + loss, backward, optimiser, the rest), and the
host syncs per step (`aten::item` / `aten::_local_scalar_dense` in the profiler) at two cloud sizes, which must not
grow with the point count. The new loop is measured in steady state: every sample's frame has been seen once, so its
extractor outputs and grouping come from the cache, as after the first pass over the training split.

    .venv/bin/python benchmarks/training_throughput.py [--sizes cpu paper] [--steps 6] [--batch-size 4] [--workers 1]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from tempfile import TemporaryDirectory

import torch

from i2pbench.batching import BatchForward, to_device
from i2pbench.grid import base_combinations, expand, parse_conf_overrides
from i2pbench.pipeline import Pipeline
from i2pbench.plugins import default_registry
from i2pbench.training import TrainConfig, Trainer
from i2pbench.training_data import TrainingSamples, collate_samples

PRESETS = {"cpu": "default", "paper": "edgeregnet-full"}
SYNCS = ("aten::item", "aten::_local_scalar_dense")


def build(size: str, *overrides: str) -> Pipeline:
    """the preset's first combination, with `KIND.KEY=VALUE` overrides."""
    registry = default_registry()
    bases = base_combinations(registry, PRESETS[size])[:1]
    torch.manual_seed(0)
    return Pipeline.build(registry, expand(bases, {}, parse_conf_overrides(list(overrides)), registry)[0])


OPTIMISERS: dict[int, torch.optim.Optimizer] = {}


def step_on(pipeline: Pipeline, batch: dict, only: str = "") -> dict[str, float]:
    """one optimiser step on a collated batch, timed by phase (`only`: "network" or "optimiser" for profiling)."""
    params = [p for m in pipeline.learned_modules().values() for p in m.parameters()]
    optimiser = OPTIMISERS.setdefault(id(pipeline), torch.optim.Adam(params, lr=1e-5))
    times: dict[str, float] = {}
    t0 = time.perf_counter()
    if only != "optimiser":
        batch = to_device(batch, torch.device("cpu"))
        t1 = time.perf_counter()
        loss, _ = BatchForward(pipeline.stages)(batch)
        t2 = time.perf_counter()
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        t3 = time.perf_counter()
        times.update(copy=t1 - t0, forward=t2 - t1, backward=t3 - t2)
    if only != "network":
        t3 = time.perf_counter()
        torch.nn.utils.clip_grad_norm_(params, 1.0)
        optimiser.step()
        times["optimiser"] = time.perf_counter() - t3
    return times


def old_loop(pipeline: Pipeline, dataset, steps: int) -> float:
    """frames/s with one frame per step, loading, extraction and grouping in the main loop (nothing cached but the
    extractor outputs, as the old trainer kept them in a dict)."""
    samples = TrainingSamples(pipeline.stages, dataset, seed=0, stage_cache=False)
    step_on(pipeline, collate_samples([samples[0]]))  # warm-up
    start = time.perf_counter()
    for i in range(1, steps + 1):
        step_on(pipeline, collate_samples([samples[i]]))
    return steps / (time.perf_counter() - start)


def new_loop(pipeline: Pipeline, dataset, steps: int, batch: int, workers: int, cache: str) -> tuple[float, dict]:
    """frames/s of Trainer's loop in steady state, and the phase shares of its steps."""
    config = TrainConfig(steps=steps + 1, batch_size=batch, workers=workers, cache_dir=cache, seed=0)
    trainer = Trainer(pipeline, dataset, None, Path(cache) / "bench.pt", config)
    warm = TrainingSamples(pipeline.stages, dataset, 0, cache)
    for i in range((steps + 1) * batch):  # the first pass over these samples fills the cache
        warm[i]
    batches = trainer.loader()
    next(batches)
    totals: dict[str, float] = {"data wait": 0.0}
    start = time.perf_counter()
    for _ in range(steps):
        t0 = time.perf_counter()
        item = next(batches)
        totals["data wait"] += time.perf_counter() - t0
        for k, v in step_on(pipeline, item).items():
            totals[k] = totals.get(k, 0.0) + v
    wall = time.perf_counter() - start
    totals["rest"] = wall - sum(totals.values())
    return steps * batch / wall, {k: v / wall for k, v in totals.items()}


def host_syncs(pipeline: Pipeline, dataset) -> tuple[int, int]:
    """item()/_local_scalar_dense calls in one batched step (grouping cached, as in steady state): in forward +
    backward, and in the optimiser (Adam reads each parameter's step counter, a CPU tensor: no device sync)."""
    samples = TrainingSamples(pipeline.stages, dataset, 0)
    batch = collate_samples([samples[0], samples[1]])
    step_on(pipeline, batch)
    counts = []
    for phase in ("network", "optimiser"):
        with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
            step_on(pipeline, batch, only=phase)
        counts.append(sum(e.count for e in prof.key_averages() if e.key in SYNCS))
    return counts[0], counts[1]


def report(size: str, args: argparse.Namespace, dataset_factory: Callable) -> None:
    dataset = dataset_factory()
    pipeline = build(size)
    print(f"\n== {size} size ({PRESETS[size]}): {pipeline.model_size_mb():.2f} MB, {torch.get_num_threads()} threads")
    old = old_loop(pipeline, dataset, args.steps)
    print(f"   old loop (1 frame/step, data and grouping in the loop): {old:.3f} frames/s")
    for batch in sorted({1, args.batch_size}):
        with TemporaryDirectory() as cache:
            new, shares = new_loop(pipeline, dataset, args.steps, batch, args.workers, cache)
        print(f"   new loop (batch {batch}, {args.workers} workers, cache): {new:.3f} frames/s, {new / old:.2f}x old")
        print("      step time: " + ", ".join(f"{k} {100 * v:.1f}%" for k, v in shares.items()))
        network = shares["forward"] + shares["backward"] + shares["optimiser"]
        print(
            f"      network forward/backward + optimiser: {100 * network:.1f}% (target >= 90%); data wait "
            f"{100 * shares['data wait']:.1f}% (target < 5%)"
        )
    n = pipeline.stages["encoder3d"].conf["num_points"]
    for points in (n // 2, n):
        network, optimiser = host_syncs(build(size, f"encoder3d.num_points={points}"), dataset)
        print(f"   host syncs per step at {points} points: {network} in forward/backward, {optimiser} in the optimiser")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", choices=sorted(PRESETS), default=["cpu", "paper"])
    parser.add_argument("--steps", type=int, default=6, help="timed steps per loop")
    parser.add_argument("--batch-size", type=int, default=4)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--threads", type=int, default=None)
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    registry = default_registry()
    for size in args.sizes:
        report(size, args, lambda: registry.dataset("synthetic")("train", {}))


if __name__ == "__main__":
    main()
