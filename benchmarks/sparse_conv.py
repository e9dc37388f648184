"""How fast i2pbench.layers.sparse runs against this machine's matmul rate, and where its time goes, on a real scan.

A KITTI scan (default: ../shared/data/kitti_odometry/sequences/00/velodyne/000000.bin, all of it) is voxelised at
0.05 m as VP2P-Match's voxel branch does it (`round((p - min p) / 0.05)`, then the first voxelisation), and brought
to strides 2, 4 and 8 by SPVCNN's 2^3 strided convolutions. On each, SPVCNN's (cr 0.5) convolutions run: the 3^3
submanifold at its channel width, and the 2^3 strided one. For each layer: its FLOPs (2 C_in C_out per neighbour
pair), the median seconds of its phases, measured one by one in one process:
- `map`: the kernel map (coordinate keys, sorting, one `searchsorted` of every output voxel + offset);
- `gather`: the rows of each offset (`index_select`);
- `matmul`: one `[pairs_k x C_in] @ [C_in x C_out]` per offset (the submanifold centre: all rows, no gather);
- `scatter`: one `scatter_add` of the concatenated products into the outputs;
and the whole layer (map cached, as it is after the first layer of a stride) forward and forward + backward.
`of matmul` is the layer's FLOP rate over the 2048^3 fp32 matmul rate; `of same-shape` over the rate of one dense
`[N_out x C_in] @ [C_in x C_out]` matmul, the ceiling a narrow layer can reach on this machine.

    .venv/bin/python benchmarks/sparse_conv.py [--scan FILE] [--device cpu|cuda] [--repeat 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from i2pbench.layers.point_voxel import SparsePoints, initial_voxelize
from i2pbench.layers.sparse import SparseConv3d, SparseVoxels, apply_kernel_map, build_kernel_map, downsample_coords

SCAN = Path(__file__).resolve().parents[2] / "shared/data/kitti_odometry/sequences/00/velodyne/000000.bin"
WIDTHS = {1: 16, 2: 16, 4: 32, 8: 64}  # SPVCNN cs at cr 0.5 for the submanifold layers of each stride


def median_seconds(fn: Callable[[], object], repeat: int, device: str) -> float:
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    fn()
    sync()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def matmul_rate(device: str, repeat: int, m: int = 2048, k: int = 2048, n: int = 2048) -> float:
    """GFLOP/s of one fp32 [m x k] @ [k x n] matmul."""
    a, b = torch.randn(m, k, device=device), torch.randn(k, n, device=device)
    return 2 * m * k * n / median_seconds(lambda: a @ b, repeat, device) / 1e9


def voxelised_scan(scan: Path, device: str) -> SparseVoxels:
    points = np.fromfile(scan, np.float32).reshape(-1, 4)
    xyz = np.round((points[:, :3] - points[:, :3].min(axis=0)) / 0.05)
    coords = torch.from_numpy(np.concatenate([xyz, np.zeros((len(xyz), 1))], axis=1).astype(np.float32))
    _, voxels = initial_voxelize(SparsePoints(torch.from_numpy(points), coords), 0.05, 0.05)
    return SparseVoxels(voxels.feats.to(device), voxels.coords.to(device))


def phases(x: SparseVoxels, layer: SparseConv3d, repeat: int, device: str) -> dict[str, float]:
    """median seconds of each phase of one layer, as `apply_kernel_map` runs them (see the module docstring)."""
    out_coords = x.coords if layer.stride == 1 else downsample_coords(x.coords, layer.stride, x.stride)
    kmap = build_kernel_map(x.coords, out_coords, layer.kernel_size, x.stride)
    kernel = layer.kernel.detach()
    rest = [(k, i, o) for k, (i, o) in enumerate(kmap.pairs) if k != kmap.identity and len(o)]
    gathered = [x.feats.index_select(0, i) for _, i, _ in rest]
    products = torch.cat([g @ kernel[k] for (k, _, _), g in zip(rest, gathered, strict=True)])
    targets = torch.cat([o for _, _, o in rest]).unsqueeze(1).expand(-1, kernel.shape[-1])
    zeros = x.feats.new_zeros(kmap.n_out, kernel.shape[-1])
    centre = kmap.identity

    def matmuls() -> list[torch.Tensor]:
        own = [x.feats @ kernel[centre]] if centre is not None else []
        return own + [g @ kernel[k] for (k, _, _), g in zip(rest, gathered, strict=True)]

    feats = x.feats.detach().requires_grad_(True)
    timed = {
        "map": lambda: build_kernel_map(x.coords, out_coords, layer.kernel_size, x.stride),
        "gather": lambda: [x.feats.index_select(0, i) for _, i, _ in rest],
        "matmul": matmuls,
        "scatter": lambda: zeros.scatter_add(0, targets, products),
        "forward": lambda: apply_kernel_map(x.feats, kernel, kmap),
        "forward+backward": lambda: apply_kernel_map(feats, layer.kernel, kmap).sum().backward(),
    }
    seconds = {name: median_seconds(fn, repeat, device) for name, fn in timed.items()}
    seconds["pairs"] = float(sum(len(o) for _, o in kmap.pairs))
    seconds["n_out"] = float(kmap.n_out)
    return seconds


def report(name: str, x: SparseVoxels, layer: SparseConv3d, rate: float, repeat: int, device: str) -> None:
    c_in, c_out = layer.kernel.shape[-2:]
    s = phases(x, layer, repeat, device)
    flops = 2 * s["pairs"] * c_in * c_out
    same_shape = matmul_rate(device, repeat, int(s["n_out"]), c_in, c_out)
    forward_rate = flops / s["forward"] / 1e9
    print(
        f"{name:<22} {len(x.coords):>7} -> {int(s['n_out']):>7} voxels, {int(s['pairs']):>8} pairs, "
        f"{flops / 1e9:6.3f} GFLOP | map {s['map'] * 1e3:7.1f} ms  gather {s['gather'] * 1e3:6.1f}  "
        f"matmul {s['matmul'] * 1e3:6.1f}  scatter {s['scatter'] * 1e3:6.1f} | forward {s['forward'] * 1e3:6.1f} ms "
        f"({forward_rate:5.1f} GFLOP/s: {forward_rate / rate:.3f} of matmul, {forward_rate / same_shape:.2f} of "
        f"same-shape {same_shape:5.1f}), +backward {s['forward+backward'] * 1e3:6.1f} ms"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scan", type=Path, default=SCAN)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    torch.manual_seed(0)
    rate = matmul_rate(args.device, args.repeat)
    print(f"fp32 matmul 2048^3: {rate:.1f} GFLOP/s on {args.device} ({torch.get_num_threads()} threads)")
    x = voxelised_scan(args.scan, args.device)
    for stride, width in WIDTHS.items():
        x = x.with_feats(torch.randn(len(x.coords), width, device=args.device))
        sub = SparseConv3d(width, width, 3).to(args.device)
        report(f"stride {stride}: 3^3 {width}->{width}", x, sub, rate, args.repeat, args.device)
        if stride < 8:
            down = SparseConv3d(width, width, 2, stride=2).to(args.device)
            report(f"stride {stride}: 2^3 /2", x, down, rate, args.repeat, args.device)
            x = down(x)


if __name__ == "__main__":
    main()
