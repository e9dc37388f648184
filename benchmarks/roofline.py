"""How close EdgeRegNet's learned stages come to what this machine can do, measured in one process.

First the machine: fp32 rates of a 2048^3 matmul, of SDPA on [1, 4, 3000, 64] and of a full-resolution 3x3 64->64
conv. Then a preset's pipeline, built through the registry (`--preset edgeregnet`: the CPU size; `edgeregnet-paper`: the
paper's), on a KITTI-sized synthetic frame (benchmarks/edgeregnet_latency.py's) with the preset's keypoint count:
each learned stage's FLOPs, counted by torch's FlopCounterMode, and its median time after a warm-up. The roofline
of a stage is the time its FLOPs would take at the measured rate of their kernel kind (conv, attention, matmul);
achieved/roofline is that time over the measured one. Uncounted work (elementwise ops, softmax, gathers, the
farthest point sampling loop) shows as a lower ratio, not as FLOPs. See docs/performance.md.

    .venv/bin/python benchmarks/roofline.py [--preset edgeregnet|edgeregnet-paper|edgeregnet-official]
        [--device cpu|cuda] [--amp bf16] [--clock wall|cpu]
    .venv/bin/python benchmarks/roofline.py --preset edgeregnet-paper --device cuda --amp off,bf16   # the GPU check

`--amp off,bf16` measures both precisions in one process, each against the machine's rates in that precision, and
ends with the per-frame latency of each: on a GPU that is the prepared check of the paper-size frame. `--rounds R`
repeats the whole measurement (rates and stages) R times and ends with the min and median over the rounds of each
stage's achieved/matmul ratio, so one slow minute on a shared machine shows as a spread, not as the result.
`--clock cpu` times rates and stages in this process's CPU seconds instead of wall seconds: on a CPU shared with
other work a stage waiting for a busy core is then not charged for it.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from edgeregnet_latency import kitti_sized_frame  # this folder is on sys.path when the script runs
from torch.utils.flop_counter import FlopCounterMode

from i2pbench.registry.build import default_registry
from i2pbench.runs.grid import base_combinations, expand
from i2pbench.stages.calling import StageInputs, call_stage
from i2pbench.stages.components import STAGES
from i2pbench.stages.pipeline import Pipeline

LEARNED = ("encoder2d", "encoder3d", "exchanger", "matcher")
KINDS = ("conv", "attention", "matmul")  # what FLOPs are timed against; FlopCounterMode counts nothing else
# wall seconds, or this process's CPU seconds: on a shared machine these move less with the neighbours' load (a
# stage's threads waiting for a busy core are not counted), for the stages and the rates alike
CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}


def cpu_attention_flops(query, key, value, *args, out_shape=None, **kwargs) -> int:
    """Q K^T and P V: 4 N M d per head. torch counts the other SDPA kernels, but not this CPU one."""
    batch, heads, n, _ = query
    return 2 * batch * heads * n * key[-2] * (query[-1] + value[-1])


ATTENTION_FORMULAS = {torch.ops.aten._scaled_dot_product_flash_attention_for_cpu: cpu_attention_flops}


def kind_of(op: object) -> str:
    name = str(op)
    return "conv" if "conv" in name else "attention" if "scaled_dot_product" in name else "matmul"


def median_seconds(
    fn: Callable[[], object], repeat: int, device: str, clock: Callable[[], float] = time.perf_counter
) -> float:
    """Median time of `fn` on `clock` after one warm-up run, waiting for the device each time."""
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    fn()
    sync()
    times = []
    for _ in range(repeat):
        start = clock()
        fn()
        sync()
        times.append(clock() - start)
    return statistics.median(times)


def machine_rates(
    device: str, repeat: int, dtype: torch.dtype = torch.float32, clock: Callable[[], float] = time.perf_counter
) -> dict[str, float]:
    """GFLOP/s of each kernel kind on this device, in `dtype` (what the stages run in under --amp)."""
    n, (h, w) = 2048, (376, 1241)
    a, b = torch.randn(n, n, device=device, dtype=dtype), torch.randn(n, n, device=device, dtype=dtype)
    q, k, v = (torch.randn(1, 4, 3000, 64, device=device, dtype=dtype) for _ in range(3))
    image = torch.randn(1, 64, h, w, device=device, dtype=dtype)
    weight = torch.randn(64, 64, 3, 3, device=device, dtype=dtype)
    flops = {"matmul": 2 * n**3, "attention": 4 * 4 * 3000 * 3000 * 64, "conv": 2 * 64 * 64 * 9 * h * w}
    runs = {
        "matmul": lambda: a @ b,
        "attention": lambda: F.scaled_dot_product_attention(q, k, v),
        "conv": lambda: F.conv2d(image, weight, padding=1),
    }
    with torch.inference_mode():
        return {kind: flops[kind] / median_seconds(runs[kind], repeat, device, clock) / 1e9 for kind in KINDS}


@dataclass
class Stage:
    kind: str
    flops: dict[str, int]  # by kernel kind
    seconds: float

    @property
    def total(self) -> int:
        return sum(self.flops.values())

    def roofline_seconds(self, rates: dict[str, float]) -> float:
        return sum(self.flops.get(kind, 0) / (rates[kind] * 1e9) for kind in KINDS)


def build_pipeline(preset: str, device: str) -> Pipeline:
    """The preset's first combination, exactly as `i2pbench run --preset PRESET` builds it (untrained weights: the
    cost of a forward pass does not depend on them)."""
    registry = default_registry()
    combination = expand(base_combinations(registry, preset), {}, {}, registry)[0]
    torch.manual_seed(0)
    return Pipeline.build(registry, combination, timeout_s=None).to(device).eval()


def stage_calls(pipeline: Pipeline, n_keypoints: int) -> dict[str, Callable[[], object]]:
    """Each learned stage on the KITTI-sized frame, called the way a run calls it (`call_stage`: declared view,
    contract check), fed its upstream stages' outputs (computed once)."""
    frame, kp2d, kp3d = kitti_sized_frame(n_keypoints)
    inputs = StageInputs(kp2d, kp3d)
    calls = {}
    for kind in LEARNED:
        stage = pipeline.stages[kind]
        calls[kind] = functools.partial(call_stage, stage, frame, inputs)
        inputs = STAGES[kind].put(inputs, calls[kind]().output)
    return calls


def count_flops(call: Callable[[], object], formulas: dict | None = ATTENTION_FORMULAS) -> dict[str, int]:
    with FlopCounterMode(display=False, custom_mapping=formulas) as counter:
        call()
    flops: dict[str, int] = {}
    for op, count in counter.get_flop_counts().get("Global", {}).items():
        flops[kind_of(op)] = flops.get(kind_of(op), 0) + count
    return flops


def measure_stages(
    pipeline: Pipeline,
    n_keypoints: int,
    repeat: int,
    device: str,
    amp: str = "off",
    clock: Callable[[], float] = time.perf_counter,
) -> tuple[list[Stage], int]:
    """Each learned stage's FLOPs and median time, and the FLOPs torch counts on its own (no attention formula);
    `amp` "bf16": the stages run under bfloat16 autocast, as `train --amp bf16` runs them."""
    autocast = torch.autocast(device, dtype=torch.bfloat16) if amp == "bf16" else contextlib.nullcontext()
    with torch.inference_mode(), autocast:
        calls = stage_calls(pipeline, n_keypoints)
        stages = [Stage(k, count_flops(c), median_seconds(c, repeat, device, clock)) for k, c in calls.items()]
        uncounted = sum(sum(count_flops(c, formulas=None).values()) for c in calls.values())
    return stages, uncounted


def print_rates(before: dict[str, float], after: dict[str, float]) -> dict[str, float]:
    """Print the rates measured before and after the stages (their drift is the machine's load changing) and return
    their mean, the rates the stages are compared with."""
    rates = {kind: (before[kind] + after[kind]) / 2 for kind in KINDS}
    print("\nmachine (GFLOP/s, median after warm-up; before and after the stages, their mean):")
    shapes = {"matmul": "2048^3", "attention": "SDPA [1, 4, 3000, 64]", "conv": "3x3 64->64 on 376 x 1241"}
    for kind in reversed(KINDS):
        ratio = rates[kind] / rates["matmul"]
        print(
            f"  {kind:9s} {shapes[kind]:26s} {before[kind]:7.1f} {after[kind]:7.1f} {rates[kind]:7.1f}"
            f"  x{ratio:.2f} of matmul"
        )
    return rates


def with_frame(stages: list[Stage]) -> list[Stage]:
    """the stages and their sum, the learned part of a frame."""
    flops = {kind: sum(s.flops.get(kind, 0) for s in stages) for kind in KINDS}
    return [*stages, Stage("per frame", flops, sum(s.seconds for s in stages))]


def print_stages(stages: list[Stage], rates: dict[str, float]) -> None:
    head = f"{'stage':10s} {'GFLOP':>8s} {'conv/attn/mm %':>15s} {'ms':>9s} {'GFLOP/s':>8s} {'x matmul':>9s}"
    print(f"\n{head} {'x roofline':>10s}")
    for stage in with_frame(stages):
        gflops, rate = stage.total / 1e9, stage.total / stage.seconds / 1e9
        mix = "/".join(f"{100 * stage.flops.get(k, 0) / max(stage.total, 1):.0f}" for k in KINDS)
        roof = stage.roofline_seconds(rates) / stage.seconds
        print(
            f"{stage.kind:10s} {gflops:8.1f} {mix:>15s} {1e3 * stage.seconds:9.1f} {rate:8.1f} "
            f"{rate / rates['matmul']:9.2f} {roof:10.2f}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="edgeregnet", help="a preset: edgeregnet (CPU size), edgeregnet-paper")
    parser.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--threads", type=int, default=torch.get_num_threads())
    parser.add_argument("--amp", type=amp_modes, default=["off"], help="off, bf16 or off,bf16 (both, in turn)")
    parser.add_argument("--rounds", type=int, default=1, help="whole measurements; >1 ends with their min and median")
    parser.add_argument("--clock", choices=sorted(CLOCKS), default="wall", help="cpu: this process's CPU seconds")
    args = parser.parse_args()
    if args.clock == "cpu" and args.device != "cpu":
        parser.error("--clock cpu times the CPU only: use --device cpu")
    torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {args.device}, {args.threads} threads, median of {args.repeat} ({args.clock})")
    print(f"load average {' '.join(open('/proc/loadavg').read().split()[:3])}")
    pipeline = build_pipeline(args.preset, args.device)
    n_keypoints = pipeline.stages["extractor2d"].conf["max_keypoints"]
    print(f"preset {args.preset}: {pipeline.combination.label}, {n_keypoints} + {n_keypoints} keypoints")
    rounds: dict[str, list[tuple[list[Stage], dict[str, float]]]] = {amp: [] for amp in args.amp}
    for r in range(args.rounds):
        for amp in args.amp:
            print(f"\n=== round {r + 1} of {args.rounds}, amp {amp}")
            rounds[amp].append(run_precision(pipeline, n_keypoints, args, amp))
    frame_seconds = {
        amp: statistics.median(sum(s.seconds for s in st) for st, _ in runs) for amp, runs in rounds.items()
    }
    if args.rounds > 1:
        for amp, runs in rounds.items():
            print_spread(amp, runs)
    print("\nper frame (learned stages): " + ", ".join(f"{amp} {s:.3f} s" for amp, s in frame_seconds.items()))


def print_spread(amp: str, runs: list[tuple[list[Stage], dict[str, float]]]) -> None:
    """each stage's achieved/matmul ratio over the rounds: min and median (and the frame's median seconds)."""
    print(f"\n=== amp {amp}: achieved / matmul over {len(runs)} rounds")
    print(f"{'stage':10s} {'min':>6s} {'median':>7s} {'max':>6s} {'median ms':>10s}")
    tables = [with_frame(stages) for stages, _ in runs]
    for i, name in enumerate(stage.kind for stage in tables[0]):
        ratios = [t[i].total / t[i].seconds / 1e9 / rates["matmul"] for t, (_, rates) in zip(tables, runs, strict=True)]
        ms = statistics.median(1e3 * t[i].seconds for t in tables)
        print(f"{name:10s} {min(ratios):6.2f} {statistics.median(ratios):7.2f} {max(ratios):6.2f} {ms:10.1f}")


def amp_modes(value: str) -> list[str]:
    modes = [m.strip() for m in value.split(",") if m.strip()]
    if not modes or set(modes) - {"off", "bf16"}:
        raise argparse.ArgumentTypeError(f"{value!r}: expected off, bf16 or off,bf16")
    return modes


def run_precision(
    pipeline: Pipeline, n_keypoints: int, args: argparse.Namespace, amp: str
) -> tuple[list[Stage], dict[str, float]]:
    """One precision's table (rates before and after the stages, in that precision); the stages and the rates."""
    dtype = torch.bfloat16 if amp == "bf16" else torch.float32
    clock = CLOCKS[args.clock]
    before = machine_rates(args.device, args.repeat, dtype, clock)
    stages, uncounted = measure_stages(pipeline, n_keypoints, args.repeat, args.device, amp, clock)
    rates = print_rates(before, machine_rates(args.device, args.repeat, dtype, clock))
    print_stages(stages, rates)
    total = sum(s.total for s in stages)
    print(f"\nFlopCounterMode without the CPU attention formula: {uncounted / 1e9:.1f} of {total / 1e9:.1f} GFLOP")
    return stages, rates


if __name__ == "__main__":
    main()
