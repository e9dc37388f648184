"""Write reference vectors of torchsparse 2.0's sparse convolution and SPVCNN's point/voxel conversions.

Run it with torchsparse 2.0.0 importable (built from source; it is no dependency of i2pbench, so use a separate
environment), on a real KITTI scan:

    /tmp/tsvenv/bin/python tools/reference/sparse.py \
        --scan ../shared/data/kitti_odometry/sequences/00/velodyne/000000.bin \
        --out tests/data/sparse_reference [--n 2048] [--seed 0] [--salt ""]

The `n` scan points nearest a seeded point 5-15 m from the sensor are moved to VP2P-Match's voxel coordinates
(`round((p - min p) / 0.05)`, batch 0) and carry (x, y, z, reflectance). A small chain of torchsparse layers with
seeded kernels (`recipe`: numpy's generator seeded by `crc32(key + salt)`) runs on them as SPVCNN chains its layers:
the first voxelisation, submanifold 3^3 convolutions at strides 1, 2 and 4, two strided 2^3 convolutions, a 1^3
one with bias, two transposed 2^3 ones back to stride 1, trilinear voxel-to-point reads at strides 4 and 1 and a
point-to-voxel average at stride 2; then the backward pass of a seeded weighted sum of two outputs (the sum itself is
not recorded: its cancellations make a scalar a poor test of equality). Written:
`inputs.npz` (points, seeded output weights, kernels), `outputs.npz` (every coordinate set, feature tensor, link and
gradient), `meta.json` (how the set was made, and the two CPU stand-ins of `add_cpu_stand_ins`: torchsparse 2.0.0's
CPU build cannot run a convolution without the first, and computes wrong trilinear gradients without the second).
tests/test_sparse_reference.py compares i2pbench.layers with them.
"""

from __future__ import annotations

import argparse
import json
import zlib
from pathlib import Path

import numpy as np
import torch
import torchsparse
import torchsparse.backend
import torchsparse.nn as spnn
import torchsparse.nn.functional as tsF
from torchsparse import SparseTensor
from torchsparse.nn.utils import get_kernel_offsets

VOXEL = 0.05  # metres, VP2P-Match's voxel branch
FIELDS = ("in", "out", "kernel", "stride", "transposed", "bias")
LAYERS = {  # name: (in, out, kernel size, stride, transposed, bias)
    "sub1": (4, 8, 3, 1, False, False),
    "down1": (8, 8, 2, 2, False, False),
    "sub2": (8, 8, 3, 1, False, False),
    "down2": (8, 16, 2, 2, False, False),
    "sub4": (16, 16, 3, 1, False, True),
    "point4": (16, 16, 1, 1, False, False),
    "up2": (16, 8, 2, 2, True, False),
    "up1": (8, 4, 2, 2, True, False),
}


def add_cpu_stand_ins() -> None:
    """Stand-ins for two CPU defects of torchsparse 2.0.0 (STAND_INS). `build_kernel_map`
    (nn/functional/build_kmap.py:66) calls `backend.build_mask_from_kmap`, which only the CUDA build binds
    (backend/pybind_cuda.cpp:41, others/sparsemapping_cuda.cu:619): on a CPU build every convolution raises
    AttributeError. The masks feed only the CUDA kernels' modes; the CPU convolution (nn/functional/conv.py,
    `convolution_forward_cpu(input, output, weight, nbmaps, nbsizes, transposed)`) never reads them, so empty ones
    leave the computed function as it is."""
    if not hasattr(torchsparse.backend, "build_mask_from_kmap"):
        torchsparse.backend.build_mask_from_kmap = lambda *args: (torch.empty(0), torch.empty(0))
    torchsparse.backend.devoxelize_backward_cpu = devoxelize_backward_as_cuda


def devoxelize_backward_as_cuda(top_grad: torch.Tensor, rows: torch.Tensor, weights: torch.Tensor, n: int):
    """the gradient of the trilinear read as torchsparse's CUDA kernel computes it (devoxelize_cuda.cu:37-57):
    voxel row r gets sum over points i and corners k with rows[i, k] = r of weights[i, k] * top_grad[i]. The CPU
    kernel (devoxelize_cpu.cpp, `devoxelize_backward_cpu`, also at the checkout's HEAD) reads
    `top_grad[rows[i, k]]`, the gradient of another point, so CPU gradients through it are wrong."""
    kept = rows >= 0
    points = torch.arange(len(rows)).unsqueeze(1).expand_as(rows)[kept]
    share = weights[kept].unsqueeze(1) * top_grad[points]
    return top_grad.new_zeros(n, top_grad.shape[1]).index_add(0, rows[kept].long(), share)


STAND_INS = {
    "build_mask_from_kmap": "empty masks (bound only in the CUDA build; unread by the CPU convolution)",
    "devoxelize_backward_cpu": "the CUDA kernel's formula (the CPU kernel reads the gradient of the wrong point)",
}


def recipe(key: str, shape: tuple[int, ...], salt: str) -> np.ndarray:
    rng = np.random.default_rng(zlib.crc32((key + salt).encode()))
    scale = 0.05 if key.endswith("bias") else 1 / np.sqrt(np.prod(shape[:-1]))
    return (scale * rng.standard_normal(shape)).astype(np.float32)


def patch(scan: Path, n: int, seed: int) -> np.ndarray:
    """[n x 4] (x, y, z, reflectance): the n points nearest a seeded point 5-15 m from the sensor."""
    points = np.fromfile(scan, np.float32).reshape(-1, 4)
    ranges = np.linalg.norm(points[:, :3], axis=1)
    candidates = np.flatnonzero((ranges > 5) & (ranges < 15))
    centre = points[np.random.default_rng(seed).choice(candidates), :3]
    return points[np.argsort(np.linalg.norm(points[:, :3] - centre, axis=1), kind="stable")[:n]]


def first_voxelization(coords: torch.Tensor, feats: torch.Tensor) -> tuple[SparseTensor, torch.Tensor]:
    """torchsparse's calls of SPVNAS's initial_voxelize (init_res = after_res = 0.05): mean features per voxel."""
    scaled = torch.cat([coords[:, :3] * VOXEL / VOXEL, coords[:, 3:]], dim=1)
    hashes = tsF.sphash(torch.floor(scaled).int())
    table = torch.unique(hashes)
    rows = tsF.sphashquery(hashes, table)
    counts = tsF.spcount(rows.int(), len(table))
    voxel_coords = torch.round(tsF.spvoxelize(torch.floor(scaled), rows, counts)).int()
    voxels = SparseTensor(tsF.spvoxelize(feats, rows, counts), voxel_coords, 1)
    voxels.cmaps.setdefault(voxels.stride, voxels.coords)
    return voxels, rows


def cells(coords: torch.Tensor, stride: int) -> torch.Tensor:
    return torch.cat([torch.floor(coords[:, :3] / stride).int() * stride, coords[:, 3:].int()], dim=1)


def to_points(voxels: SparseTensor, coords: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """trilinear read of voxel features at the points: (features, corner rows [N x 8], weights [N x 8])."""
    stride = voxels.s[0]
    corners = tsF.sphash(cells(coords, stride), get_kernel_offsets(2, voxels.s, 1))
    rows = tsF.sphashquery(corners, tsF.sphash(voxels.C))
    weights = tsF.calc_ti_weights(coords, rows, scale=stride).transpose(0, 1).contiguous()
    rows = rows.transpose(0, 1).contiguous()
    return tsF.spdevoxelize(voxels.F, rows, weights), rows, weights


def to_voxels(voxels: SparseTensor, coords: torch.Tensor, feats: torch.Tensor) -> torch.Tensor:
    """mean of the points' features in each voxel of `voxels`."""
    rows = tsF.sphashquery(tsF.sphash(cells(coords, voxels.s[0])), tsF.sphash(voxels.C))
    return tsF.spvoxelize(feats, rows, tsF.spcount(rows.int(), len(voxels.C)))


def build(salt: str) -> tuple[dict[str, spnn.Conv3d], dict[str, np.ndarray]]:
    layers, kernels = {}, {}
    for name, (c_in, c_out, size, stride, transposed, bias) in LAYERS.items():
        layer = spnn.Conv3d(c_in, c_out, size, stride, bias=bias, transposed=transposed)
        for key, param in layer.state_dict().items():
            value = recipe(f"{name}.{key}", tuple(param.shape), salt)
            param.copy_(torch.from_numpy(value))
            kernels[f"{name}.{key}"] = value
        layers[name] = layer
    return layers, kernels


def run(points: np.ndarray, salt: str, seed: int) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """the chain of the module docstring on one patch: (inputs, outputs) as the files hold them."""
    layers, kernels = build(salt)
    xyz = np.round((points[:, :3] - points[:, :3].min(axis=0)) / VOXEL)
    coords = torch.from_numpy(np.concatenate([xyz, np.zeros((len(xyz), 1))], axis=1).astype(np.float32))
    x0, rows0 = first_voxelization(coords, torch.from_numpy(points.copy()))
    x0.F = x0.F.detach().requires_grad_(True)
    out = {"coords1": x0.C, "voxel_rows1": rows0, "voxelized": x0.F}
    t, kept = x0, {}
    for name in LAYERS:
        t = kept[name] = layers[name](t)
        out[name], out[f"coords_{name}"] = t.F, t.C
    out["points4"], out["corner_rows4"], out["corner_weights4"] = to_points(kept["point4"], coords)
    out["points1"], out["corner_rows1"], out["corner_weights1"] = to_points(kept["up1"], coords)
    out["voxels2"] = to_voxels(kept["sub2"], coords, out["points4"][:, :8])
    rng = np.random.default_rng(seed)
    weights = {k: rng.standard_normal(tuple(out[k].shape)).astype(np.float32) for k in ("points1", "voxels2")}
    loss = sum((out[k] * torch.from_numpy(w)).sum() for k, w in weights.items())
    loss.backward()
    out["grad_voxelized"] = x0.F.grad
    for name, layer in layers.items():
        for key, param in layer.named_parameters():
            out[f"grad_{name}.{key}"] = param.grad
    inputs = {"coords": coords.numpy(), "feats": points, **{f"weight_{k}": w for k, w in weights.items()}}
    inputs.update({f"param_{k}": v for k, v in kernels.items()})
    return inputs, {k: v.detach().numpy() for k, v in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scan", type=Path, required=True, help="a KITTI velodyne .bin")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--n", type=int, default=2048, help="scan points in the patch")
    parser.add_argument("--seed", type=int, default=0, help="patch centre and output weights")
    parser.add_argument("--salt", default="", help="the kernel recipe's salt")
    args = parser.parse_args()
    torch.set_num_threads(1)
    add_cpu_stand_ins()
    inputs, outputs = run(patch(args.scan, args.n, args.seed), args.salt, args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out / "inputs.npz", **inputs)
    np.savez_compressed(args.out / "outputs.npz", **outputs)
    meta = {
        "scan": "/".join(args.scan.resolve().parts[-4:]),
        "n": args.n,
        "seed": args.seed,
        "salt": args.salt,
        "torchsparse": torchsparse.__version__,
        "torch": torch.__version__,
        "stand_ins": STAND_INS,
        "layers": {k: dict(zip(FIELDS, v, strict=True)) for k, v in LAYERS.items()},
        "voxels": {
            s: int(len(outputs[k])) for s, k in (("1", "coords1"), ("2", "coords_down1"), ("4", "coords_down2"))
        },
    }
    (args.out / "meta.json").write_text(json.dumps(meta, indent=2) + "\n")


if __name__ == "__main__":
    main()
