"""Seconds of one training step of VP2P-Match's official size, and the share of its pose term, on a real frame.

The `vp2p-match-official` preset's stages at the authors' sizes (or smaller, `--points`, `--crop`), one KITTI frame
(default ../shared/data/kitti_odometry, its first frame) under a protocol transform, prepared once; then `--steps`
optimiser steps of the matcher's `batch_loss` (Adam, lr 1e-4), each timed in phases measured in one process:
`forward+loss` (the network and the three terms), `pose` (the EPro-PnP term alone, recomputed on the same outputs
with its backward), `step` (forward, loss, backward and the Adam update). The first step carries allocation and
`torch.func`'s warm-up, so the medians leave it out. Prints the machine's load average beside the numbers.

    .venv/bin/python benchmarks/vp2p_train_step.py [--data-root DIR] [--device cpu|cuda] [--steps 4]
        [--points 40960] [--crop 512 160] [--threads 1]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import torch
from i2pbench_vp2p_match.official.loss import pose_loss
from i2pbench_vp2p_match.official.stages import SUP, unpadded

from i2pbench.api import Features
from i2pbench.registry.build import default_registry
from i2pbench.runs.grid import expand
from i2pbench.scoring.protocol import Protocol
from i2pbench.stages.pipeline import Pipeline

DATA = Path(__file__).resolve().parents[2] / "shared/data/kitti_odometry"


def prepared_stage(args: argparse.Namespace):
    """the official matcher in training mode on `args.device` and one frame's prepared inputs (a batch of one)."""
    registry = default_registry()
    crop = list(args.crop)
    confs = {"extractor3d": {"max_keypoints": args.points}, "extractor2d": {"crop": crop}, "matcher": {"crop": crop}}
    (row,) = registry.preset_rows("vp2p-match-official")
    pipeline = Pipeline.build(registry, expand([row], {}, confs, registry)[0])
    dataset = registry.dataset("kitti")("all", {"root": str(args.data_root)})
    frame = Protocol(seed=1).apply(dataset.load(dataset.frame_ids()[0]))
    matcher = pipeline.stages["matcher"].to(args.device).train()
    return matcher, matcher.one(frame, pipeline.stages["extractor2d"](frame), pipeline.stages["extractor3d"](frame))


def timed(fn, device: str) -> tuple[float, object]:
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    sync()
    start = time.perf_counter()
    out = fn()
    sync()
    return time.perf_counter() - start, out


def one_step(matcher, optimizer, inputs: dict, sup: dict, device: str) -> tuple[float, float, float, float, dict]:
    """(forward+loss s, whole step s, pose term s, loss, terms) of one optimiser step; the pose term is recomputed
    on the step's outputs, detached, so its time is its own forward and backward."""
    t_loss, (loss, terms) = timed(lambda: matcher.batch_loss(inputs, Features(None, None), None, None), device)
    t_back, _ = timed(lambda: (optimizer.zero_grad(), loss.backward(), optimizer.step()), device)
    with torch.no_grad():
        out = {k: v[0].detach().requires_grad_(True) for k, v in matcher.batched(inputs).items()}
    t_pose, _ = timed(lambda: pose_loss(out, sup, inputs["pc"][0], matcher.conf).backward(), device)
    return t_loss, t_loss + t_back, t_pose, loss.item(), terms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data-root", type=Path, default=DATA)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--steps", type=int, default=4)
    parser.add_argument("--points", type=int, default=40960)
    parser.add_argument("--crop", type=int, nargs=2, default=(512, 160))
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    matcher, inputs = prepared_stage(args)
    optimizer = torch.optim.Adam(matcher.parameters(), lr=1e-4)
    sup = unpadded({k.removeprefix(SUP): v for k, v in inputs.items() if k.startswith(SUP)}, 0)
    rows = []
    for step in range(args.steps):
        load = os.getloadavg()[0]
        t_loss, t_step, t_pose, loss, terms = one_step(matcher, optimizer, inputs, sup, args.device)
        rows.append((t_loss, t_step, t_pose))
        print(f"step {step}: forward+loss {t_loss:.2f} s, step {t_step:.2f} s, pose {t_pose:.2f} s, "
              f"load {load:.1f}, loss {loss:.2f} {terms}", flush=True)  # fmt: skip
    warm = rows[1:] or rows
    loss_s, step_s, pose_s = (statistics.median(r[i] for r in warm) for i in range(3))
    print(f"median of steps 1-{len(rows) - 1}: step {step_s:.2f} s, forward+loss {loss_s:.2f} s, pose term "
          f"{pose_s:.2f} s = {pose_s / step_s:.3f} of the step; {int(sup['pc_kpt_idx'].numel())} anchors, "
          f"{inputs['pc'].shape[-1]} points, crop {args.crop[0]} x {args.crop[1]}, {args.device}")  # fmt: skip


if __name__ == "__main__":
    main()
