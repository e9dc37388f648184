"""Training throughput: the old loop (one frame per step, data work and point grouping in the loop) against the
batched loop (DataLoader workers, per-frame grouping cache, padded batches), in one process, on synthetic/train.

For each variant (`cpu-size`: preset edgeregnet; `paper`: edgeregnet-paper) it prints frames/s of each loop and its
ratio to the old one, their steps taken in turn (so a busy machine slows all of them alike), where a step's time goes
(data work or data wait, host-to-device copy, forward + loss, backward, optimiser), and the host syncs per step
(`aten::item` / `aten::_local_scalar_dense` in the profiler) at two cloud sizes, which must not grow with the point
count. The new loop is measured in steady state: every sample's frame has been seen once, so its extractor outputs
and grouping come from the cache, as after the first pass over the training split.

    .venv/bin/python benchmarks/training_throughput.py [--sizes cpu-size paper] [--steps 6] [--batch-size 4]
        [--workers 1]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from tempfile import TemporaryDirectory

import torch

from i2pbench.registry.build import default_registry
from i2pbench.runs.grid import base_combinations, expand, parse_conf_overrides
from i2pbench.stages.pipeline import Pipeline
from i2pbench.training.batching import BatchForward, to_device
from i2pbench.training.config import TrainConfig
from i2pbench.training.loop import Trainer
from i2pbench.training.samples import TrainingSamples, collate_samples

PRESETS = {"cpu-size": "edgeregnet", "paper": "edgeregnet-paper"}
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


class OldLoop:
    """one frame per step, loading, extraction and grouping in the main loop (nothing cached but the extractor
    outputs, as the old trainer kept them in a dict)."""

    def __init__(self, pipeline: Pipeline, dataset) -> None:
        self.pipeline, self.samples, self.index = pipeline, TrainingSamples(pipeline.stages, dataset, 0, None, False), 0
        self.step()  # warm-up

    def step(self) -> tuple[int, dict[str, float]]:
        start = time.perf_counter()
        batch = collate_samples([self.samples[self.index]])
        data = time.perf_counter() - start
        self.index += 1
        return 1, {"data in loop": data, **step_on(self.pipeline, batch)}


class NewLoop:
    """Trainer's loader in steady state: every sample's frame seen once, so extraction and grouping are cached."""

    def __init__(self, pipeline: Pipeline, dataset, steps: int, batch: int, workers: int, cache: str) -> None:
        config = TrainConfig(steps=steps + 1, batch_size=batch, workers=workers, cache_dir=cache, seed=0)
        trainer = Trainer(pipeline, dataset, None, Path(cache) / "bench.pt", config)
        warm = TrainingSamples(pipeline.stages, dataset, 0, cache)
        for i in range((steps + 1) * batch):  # the first pass over these samples fills the cache
            warm[i]
        self.pipeline, self.batch, self.batches = pipeline, batch, trainer.loader()
        step_on(pipeline, next(self.batches))  # warm-up

    def step(self) -> tuple[int, dict[str, float]]:
        start = time.perf_counter()
        item = next(self.batches)
        return self.batch, {"data wait": time.perf_counter() - start, **step_on(self.pipeline, item)}


def interleaved(loops: dict[str, OldLoop | NewLoop], steps: int) -> dict[str, tuple[float, dict[str, float]]]:
    """frames/s and phase shares of each loop, their steps taken in turn so every loop sees the same machine load."""
    frames = dict.fromkeys(loops, 0)
    phases: dict[str, dict[str, float]] = {name: {} for name in loops}
    for _ in range(steps):
        for name, loop in loops.items():
            n, times = loop.step()
            frames[name] += n
            for k, v in times.items():
                phases[name][k] = phases[name].get(k, 0.0) + v
    out = {}
    for name, times in phases.items():
        wall = sum(times.values())
        out[name] = (frames[name] / wall, {k: v / wall for k, v in times.items()})
    return out


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
    with TemporaryDirectory() as one, TemporaryDirectory() as many:
        loops = {
            "old loop (1 frame/step, data and grouping in the loop)": OldLoop(pipeline, dataset),
            f"new loop (batch 1, {args.workers} workers, cache)": NewLoop(
                pipeline, dataset, args.steps, 1, args.workers, one
            ),
        }
        if args.batch_size > 1:
            name = f"new loop (batch {args.batch_size}, {args.workers} workers, cache)"
            loops[name] = NewLoop(pipeline, dataset, args.steps, args.batch_size, args.workers, many)
        results = interleaved(loops, args.steps)
    old = next(iter(results.values()))[0]
    for name, (rate, shares) in results.items():
        print(f"   {name}: {rate:.3f} frames/s, {rate / old:.2f}x old")
        print("      step time: " + ", ".join(f"{k} {100 * v:.1f}%" for k, v in shares.items()))
        network = shares["forward"] + shares["backward"] + shares["optimiser"]
        print(f"      network forward/backward + optimiser: {100 * network:.1f}% (target >= 90%)")
    n = pipeline.stages["encoder3d"].conf["num_points"]
    for points in (n // 2, n):
        network, optimiser = host_syncs(build(size, f"encoder3d.num_points={points}"), dataset)
        print(f"   host syncs per step at {points} points: {network} in forward/backward, {optimiser} in the optimiser")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", choices=sorted(PRESETS), default=["cpu-size", "paper"])
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
