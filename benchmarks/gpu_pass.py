"""The GPU figure: the official EdgeRegNet frame and the default grid on one device, as a small JSON.

Run by benchmarks/gpu_pass.sh (which installs first); on a CPU it runs the same way (`--device cpu`), which is
how it is kept tested where no GPU is lent. Writes OUT/gpu_pass.json:
- `official_frame`: the authors' inference sizes (benchmarks/edgeregnet_official.py: `--keypoints` edge pixels and
  points, a 20,480-point cloud, the 1250 x 376 canvas), median seconds per learned stage after a warm-up (each
  waited for on the device) and their sum, and the peak device memory of each stage;
- `default_grid`: `i2pbench run --preset default` on `--frames` synthetic frames on the device, its per-stage median
  latency from the leaderboard and the run's peak device memory;
- the device, torch, the paper's 0.18 s per frame (an RTX 3090) beside them, and the load average.
Peak memory on CUDA is torch's max_memory_allocated; on a CPU, the process's peak resident set (ru_maxrss).

    .venv/bin/python benchmarks/gpu_pass.py --out DIR [--device cuda] [--frames 6] [--keypoints 3000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import torch
from edgeregnet_latency import kitti_sized_frame  # this folder is on sys.path when the script runs
from edgeregnet_official import stage_runs
from i2pbench_edgeregnet.method import official_stages

from i2pbench.boards.leaderboard import LATENCY_MEDIAN, stage_latency
from i2pbench.cli import main as i2pbench

PAPER_SECONDS = 0.18  # EdgeRegNet's reported inference time per frame, RTX 3090
LEARNED = ("encoder2d", "encoder3d", "exchanger", "matcher")


def synchronize(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize(device)


def reset_peak(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.reset_peak_memory_stats(device)


def peak_mb(device: str) -> float:
    """peak memory since the last reset_peak: the device's allocations, or this process's resident set on a CPU."""
    if device.startswith("cuda"):
        return torch.cuda.max_memory_allocated(device) / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**10


def median_seconds(fn: Callable[[], object], repeat: int, device: str) -> float:
    """median wall seconds of fn after one warm-up, waiting for the device each time."""
    fn()
    synchronize(device)
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        synchronize(device)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def official_frame(device: str, keypoints: int, repeat: int) -> dict:
    stages = {kind: module.to(device).eval() for kind, module in official_stages().items()}
    frame, kp2d, kp3d = kitti_sized_frame(keypoints)
    seconds, memory = {}, {}
    with torch.inference_mode():
        for kind, run in stage_runs(stages, frame, kp2d, kp3d, device).items():
            reset_peak(device)
            seconds[kind] = median_seconds(run, repeat, device)
            memory[kind] = peak_mb(device)
    return {"keypoints": keypoints, "stage_s": seconds, "frame_s": sum(seconds.values()), "peak_memory_mb": memory}


def default_grid(device: str, frames: int, out: Path) -> dict:
    """`i2pbench run --preset default` on synthetic frames, in this process (so its peak memory is readable)."""
    reset_peak(device)
    args = ["run", "--preset", "default", "--dataset", "synthetic", "--split", "test"]
    args += ["--data-root", str(out / "synthetic"), "--data-conf", f"frames.test={frames}", "--device", device]
    args += ["--runs-dir", str(out / "runs"), "--out", str(out / "default-grid"), "--threads", "1", "--quiet"]
    if i2pbench(args) != 0:
        raise SystemExit("gpu_pass: the default grid's run failed")
    row = pd.read_csv(out / "default-grid.csv").iloc[0]
    return {
        "combination": row["combination"],
        "weights": row["weights"],
        "frames": int(row["frames"]),
        "stage_ms": {kind: float(row[stage_latency(kind, "median")]) for kind in LEARNED},
        "frame_ms": float(row[LATENCY_MEDIAN]),
        "peak_memory_mb": peak_mb(device),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path, help="folder for gpu_pass.json and the run's files")
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--frames", type=int, default=6, help="synthetic frames of the default grid")
    parser.add_argument("--keypoints", type=int, default=3000, help="edge pixels and points of the official frame")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        print(f"gpu_pass: --device {args.device} but torch {torch.__version__} sees no CUDA device", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    name = torch.cuda.get_device_name(args.device) if args.device.startswith("cuda") else "cpu"
    report = {
        "device": name,
        "torch": torch.__version__,
        "paper_frame_s": PAPER_SECONDS,
        "load_average": Path("/proc/loadavg").read_text().split()[:3],
        "official_frame": official_frame(args.device, args.keypoints, args.repeat),
        "default_grid": default_grid(args.device, args.frames, args.out),
    }
    (args.out / "gpu_pass.json").write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
