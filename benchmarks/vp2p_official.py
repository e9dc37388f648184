"""Seconds per frame of VP2P-Match's network at the authors' size, i2pbench's official modules beside the authors' code,
in one process on this CPU, and how far apart their outputs are at that size.

The authors' size: 40,960 points of a KITTI scan downsampled at 0.1 m (drawn with replacement when the scan has
fewer), a 160 x 512 crop of the half-size camera image (their `img_H`, `img_W`). Both networks get the same seeded
recipe weights. The authors' side needs torchsparse 2.0.0 and their checkout, so run it from the environment that has
torchsparse (tools/reference/sparse.py's docstring); without `--checkout` only i2pbench's side is timed. The authors'
side runs with tools/reference's CPU stand-ins for `pointnet2_ops` (plain-torch loops: its farthest point sampling
and ball query are slower than the CUDA kernels they replace, so its time is an upper bound of their code on a CPU).

    /tmp/tsvenv/bin/python benchmarks/vp2p_official.py --checkout /work/peers/VP2P-Match [--points 40960] [--repeat 3]
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import open3d as o3d
import torch
from i2pbench_vp2p_match.official.network import VP2PMatchNet
from i2pbench_vp2p_match.reference import recipe_state

ROOT = Path(__file__).resolve().parents[1]
FRAME = ROOT.parent / "shared/data/kitti_odometry/sequences/00"


def load_tool(name: str):
    spec = importlib.util.spec_from_file_location(f"reference_{name}", ROOT / "tools" / "reference" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def median_seconds(fn, repeat: int) -> float:
    fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def frame_inputs(points: int) -> list[torch.Tensor]:
    """pc, intensity, sn and img at the authors' size, batch of one."""
    tool = load_tool("vp2p")
    scan = np.fromfile(FRAME / "velodyne" / "000000.bin", np.float32).reshape(-1, 4)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan[:, :3].astype(np.float64)))
    cloud.colors = o3d.utility.Vector3dVector(np.repeat(scan[:, 3:4].astype(np.float64), 3, axis=1))
    cloud = cloud.voxel_down_sample(0.1)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamRadius(0.6))
    n, rng = len(cloud.points), np.random.default_rng(0)
    chosen = rng.permutation(n)[:points] if n >= points else np.concatenate([np.arange(n), rng.choice(n, points - n)])
    data = {
        "pc": np.asarray(cloud.points)[chosen].T,
        "intensity": np.asarray(cloud.colors)[chosen, :1].T,
        "sn": np.asarray(cloud.normals)[chosen].T,
        "img": tool.frame_image(FRAME, "000000", (160, 512)),
    }
    return [torch.from_numpy(np.ascontiguousarray(data[k], dtype=np.float32)).unsqueeze(0) for k in data]


def authors_network(checkout: Path):
    """the authors' VP2PMatchNet from the checkout, with tools/reference's CPU stand-ins."""
    load_tool("sparse").add_cpu_stand_ins()
    load_tool("pointnet2_cpu").install()
    sys.path.insert(0, str(checkout))
    from models.triplet_network import VP2PMatchNet as Theirs
    from utils.options import Options

    return Theirs(Options())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkout", type=Path, help="junshengzhou/VP2P-Match (needs torchsparse)")
    parser.add_argument("--points", type=int, default=40960)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    inputs = frame_inputs(args.points)
    ours = VP2PMatchNet()
    state, _ = recipe_state({k: list(v.shape) for k, v in ours.state_dict().items()}, "")
    ours.load_state_dict(state)
    nets = {"i2pbench": ours.eval()}
    if args.checkout:
        theirs = authors_network(args.checkout)
        theirs.load_state_dict(state)
        nets["authors"] = theirs.eval()
    print(f"{args.points} points, image 160 x 512, {torch.get_num_threads()} threads")
    outputs = {}
    cuda = torch.Tensor.cuda
    torch.Tensor.cuda = lambda self, *a, **k: self  # the authors' forward puts its batch indices on the GPU
    try:
        for name, net in nets.items():
            with torch.no_grad():
                outputs[name] = net(*inputs)
                seconds = median_seconds(lambda net=net: net(*inputs), args.repeat)
            print(f"{name:>8}: {seconds:6.2f} s per frame (median of {args.repeat})")
    finally:
        torch.Tensor.cuda = cuda
    if len(outputs) == 2:
        names = ("pixel_feat", "point_feat", "img_score", "pc_score")
        for name, a, b in zip(names, outputs["i2pbench"], outputs["authors"], strict=True):
            error = float((a - b).abs().max() / b.abs().max())
            print(f"{name:>10}: max |i2pbench - authors| / max |authors| = {error:.1e}")


if __name__ == "__main__":
    main()
