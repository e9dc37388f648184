"""CPU time of the official EdgeRegNet size per frame, beside the paper's 0.18 s on an RTX 3090 (docs/edgeregnet.md).

A KITTI-sized frame (benchmarks/edgeregnet_latency.py) with the authors' inference sizes: 3000 edge pixels, 3000 edge
points, a 20,480-point cloud, the 1250 x 376 canvas. Each of the four learned stages runs through its `prepare`
(canvas, normalisations, FPS from a seeded start and ball queries) and `forward` in eval mode, then the matcher's
mutual-max filter and top-3000 FOV restriction: everything the authors' `AttentionModule.forward` and test.py do
before EPnP. Prints the median of `--repeat` runs (after one warm-up) per stage and in total, per thread count.

    .venv/bin/python benchmarks/edgeregnet_official.py [--repeat 3] [--threads 1 2]
"""

from __future__ import annotations

import argparse

import torch
from edgeregnet_latency import kitti_sized_frame, median_seconds
from i2pbench_edgeregnet.method import official_stages
from i2pbench_edgeregnet.official.matching import filter_matches

KEYPOINTS = 3000


def stage_runs(stages: dict, frame, kp2d, kp3d, device: str = "cpu") -> dict:
    """one callable per stage on `device` (inputs prepared there), each fed the previous stage's output (computed
    once here)."""
    enc2d, enc3d, exchanger, matcher = (stages[k] for k in ("encoder2d", "encoder3d", "exchanger", "matcher"))

    def batch(d: dict) -> dict:
        return {k: v[None] for k, v in d.items()}

    def run2d():
        return torch.nn.Module.__call__(enc2d, batch(enc2d.prepare(frame, kp2d, device=device)))

    def run3d():
        return enc3d.forward(batch(enc3d.prepare(frame, kp3d, device=device)))

    d2, d3 = run2d(), run3d()

    def exchange():
        return exchanger.forward(batch(exchanger.prepare(frame, kp2d, kp3d, device=device)), d2, d3)

    g2, g3 = exchange()

    def match():
        scores = matcher.forward(g2, g3)["log_assignment"][0]
        return filter_matches(scores, 0.0)

    return {"encoder2d": run2d, "encoder3d": run3d, "exchanger": exchange, "matcher": match}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    frame, kp2d, kp3d = kitti_sized_frame(KEYPOINTS)
    stages = official_stages()
    for module in stages.values():
        module.eval()
    for threads in args.threads:
        torch.set_num_threads(threads)
        with torch.no_grad():
            runs = stage_runs(stages, frame, kp2d, kp3d)
            times = {kind: median_seconds(fn, args.repeat) for kind, fn in runs.items()}
        parts = ", ".join(f"{kind} {t:.2f}" for kind, t in times.items())
        print(f"{threads} thread(s): {sum(times.values()):.2f} s per frame ({parts}); paper: 0.18 s on an RTX 3090")


if __name__ == "__main__":
    main()
