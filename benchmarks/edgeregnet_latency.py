"""Per-stage CPU latency and model size of EdgeRegNet's learned stages at KITTI size, its paper and cpu-size variants.

A synthetic KITTI-sized frame (1241 x 376 image, a 120k-point 64-beam-like sweep) with 3000 + 3000 keypoints for the
paper variant and configs.CPU_KEYPOINTS + CPU_KEYPOINTS for the cpu-size one; content does not change the cost of any
stage. Prints the median of `--repeat` inference runs per stage (after one warm-up), the farthest point sampling
20,480 -> 5,120 on its own, one training step (forward, loss, backward) and the float32 parameter size.

    .venv/bin/python benchmarks/edgeregnet_latency.py [--repeat 5] [--threads 2] [--variants paper cpu-size]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch
from i2pbench_edgeregnet import configs

from i2pbench.api import Features, Frame, Keypoints2D, Keypoints3D
from i2pbench.geometry.transforms import in_image, project
from i2pbench.layers.pointnet2 import farthest_point_sampling
from i2pbench.registry.build import build_registry

W, H, N_POINTS = 1241, 376, 120_000
K = np.array([[718.9, 0.0, 607.2], [0.0, 718.9, 185.2], [0.0, 0.0, 1.0]])


def kitti_sized_frame(n_keypoints: int, seed: int = 0) -> tuple[Frame, Keypoints2D, Keypoints3D]:
    """a LiDAR-like sweep seen by a forward camera; 2D keypoints are projections of visible 3D ones plus noise."""
    rng = np.random.default_rng(seed)
    azimuth, elevation = rng.uniform(-np.pi, np.pi, N_POINTS), np.deg2rad(rng.uniform(-25, 3, N_POINTS))
    r = rng.uniform(3, 80, N_POINTS)
    xyz = np.c_[r * np.cos(elevation) * np.cos(azimuth), r * np.cos(elevation) * np.sin(azimuth), r * np.sin(elevation)]
    points = np.c_[xyz, rng.uniform(0, 1, N_POINTS)].astype(np.float32)
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]  # camera z along LiDAR x
    image = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    frame = Frame("synthetic", "0", image, points, np.zeros(N_POINTS, np.int16), r.astype(np.float32), K, T)
    kp3d = Keypoints3D.from_index(frame, rng.choice(N_POINTS, n_keypoints, replace=False))
    uv, front = project(K, T, kp3d.xyz.astype(np.float64))
    seen = uv[in_image(uv, front, (W, H))]
    noise = rng.uniform(0, [W - 1, H - 1], (n_keypoints - len(seen), 2))
    kp2d = Keypoints2D(np.clip(np.r_[seen, noise], 0, [W - 1, H - 1]).astype(np.float32))
    return frame, kp2d, kp3d


def median_seconds(fn: Callable[[], object], repeat: int) -> float:
    fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def build(conf: dict[str, dict]) -> dict[str, torch.nn.Module]:
    registry = build_registry()
    return {kind: registry.component(kind, name)(conf[kind]) for kind, name in configs.COMPONENTS.items()}


def measure(label: str, conf: dict[str, dict], n_keypoints: int, repeat: int) -> None:
    torch.manual_seed(0)
    stages = build(conf)
    frame, kp2d, kp3d = kitti_sized_frame(n_keypoints)
    e2, e3, ex, matcher = stages.values()
    sizes = {kind: sum(p.numel() for p in m.parameters()) * 4 / 2**20 for kind, m in stages.items()}
    print(f"\n== {label}: {len(kp2d)} + {len(kp3d)} keypoints, {sum(sizes.values()):.2f} MB float32")
    for kind, mb in sizes.items():
        print(f"   {kind:10s} {configs.COMPONENTS[kind]:15s} {mb:7.2f} MB")
    with torch.inference_mode():
        d2, d3 = e2(frame, kp2d), e3(frame, kp3d)
        features = ex(frame, kp2d, kp3d, Features(d2, d3))
        seconds = {
            "encoder2d": median_seconds(lambda: e2(frame, kp2d), repeat),
            "encoder3d": median_seconds(lambda: e3(frame, kp3d), repeat),
            "exchanger": median_seconds(lambda: ex(frame, kp2d, kp3d, Features(d2, d3)), repeat),
            "matcher": median_seconds(lambda: matcher(frame, kp2d, kp3d, features), repeat),
        }
        cloud = torch.rand(1, e3.conf["num_points"], 3)
        fps = median_seconds(lambda: farthest_point_sampling(cloud, e3.conf["sa1"]["npoint"]), repeat)
    for kind, s in seconds.items():
        print(f"   {kind:10s} {s:7.3f} s")
    print(f"   {'total':10s} {sum(seconds.values()):7.3f} s per frame (inference)")
    print(f"   fps {e3.conf['num_points']} -> {e3.conf['sa1']['npoint']}: {fps:.3f} s (inside encoder3d)")

    def train_step() -> None:
        loss, _ = matcher.loss(frame, kp2d, kp3d, ex(frame, kp2d, kp3d, Features(e2(frame, kp2d), e3(frame, kp3d))))
        loss.backward()

    print(f"   training step (forward + loss + backward): {median_seconds(train_step, max(1, repeat // 2)):.2f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--threads", type=int, default=torch.get_num_threads())
    parser.add_argument("--variants", nargs="+", default=["paper", "cpu-size"], choices=["paper", "cpu-size"])
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {args.threads} threads, median of {args.repeat}")
    variants = {"paper": (configs.PAPER, configs.PAPER_KEYPOINTS), "cpu-size": (configs.CPU, configs.CPU_KEYPOINTS)}
    for name in args.variants:
        measure(name, *variants[name], args.repeat)


if __name__ == "__main__":
    main()
