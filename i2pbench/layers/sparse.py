"""Sparse 3D convolution in plain torch, computing torchsparse 2.0's function (SPVCNN's voxel branch, VP2P-Match).

Why: torchsparse has no wheel and its CPU backend builds only from source; a gather / matmul / scatter written with
torch ops runs forward and backward on any device with nothing compiled. Each output voxel finds its neighbour under
every kernel offset by an exact search: coordinates become linear keys (`CoordinateKeys`), so the key of a voxel
plus an offset is its key plus the offset's, and the sorted output keys plus an offset's key are sorted queries into
the sorted input keys: one `searchsorted` per (x, y) column of offsets (`_column_search`). torchsparse hashes with a
60-bit FNV-1a instead (`voxel_hash`, kept for its voxel order), which could in principle collide; exact keys agree
with it whenever it does not. The gathered rows of each offset are multiplied by that offset's `[C_in x C_out]`
slice of the kernel and all products are scatter-added into the output rows at once; the centre offset of a
submanifold convolution maps every voxel to itself and is one plain matmul.

What is torchsparse's and kept so that its weights and outputs carry over unchanged:
- coordinates are int32 `[N x 4]` rows `(x, y, z, batch)`, in voxel units of the finest grid; a tensor at stride `s`
  holds multiples of `s`;
- a kernel is `[K^3 x C_in x C_out]` (`[C_in x C_out]` when K = 1) in the offset order of `kernel_offsets`: x fastest
  for an odd K^3, z fastest for an even one (torchsparse/nn/utils/kernel.py, `get_kernel_offsets`, v2.0.0);
  offsets are multiples of the input's stride, and output voxel `o` sums `x[o + offset_k] @ kernel[k]`;
- a strided convolution (stride = kernel size, as torchsparse's CPU path requires) puts its outputs at
  `trunc(c / (s * stride)) * s * stride`, deduplicated and sorted by (batch, x, y, z) as `torch.unique` sorts them
  (torchsparse/nn/functional/downsample.py); trunc, not floor: coordinates are expected non-negative (VP2P-Match
  subtracts the cloud's minimum), and a negative one rounds towards zero exactly as there;
- a transposed convolution reuses the kernel map of the strided convolution that made its input, swapped: it returns
  to that convolution's input coordinates, in their order;
- dilation is not applied (torchsparse 2.0's hashmap path ignores it too), so it is not offered.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import nn

REVISION = 0  # bump when an output of this module changes for the same inputs (see i2pbench.layers)

_FNV_OFFSET = 14695981039346656037 - (1 << 64)  # the uint64 basis as the int64 with the same bits
_FNV_PRIME = 1099511628211
_LOW_60 = (1 << 60) - 1


def voxel_hash(coords: torch.Tensor) -> torch.Tensor:
    """[... x 4] int coordinates -> [...] int64: torchsparse's FNV-1a hash (backend/hash/hash_cpu.cpp), bit for bit.

    int64 products wrap modulo 2^64 like the C++ uint64 ones; each coordinate enters as its uint32 bits."""
    h = torch.full(coords.shape[:-1], _FNV_OFFSET, dtype=torch.int64, device=coords.device)
    for j in range(4):
        h = (h ^ (coords[..., j].to(torch.int64) & 0xFFFFFFFF)) * _FNV_PRIME
    return ((h >> 60) & 0xF) ^ (h & _LOW_60)


def kernel_offsets(kernel_size: int, tensor_stride: int = 1, device: torch.device | str = "cpu") -> torch.Tensor:
    """[K^3 x 3] int32 neighbour offsets in torchsparse's kernel order (see the module's docstring)."""
    steps = torch.arange(-kernel_size // 2 + 1, kernel_size // 2 + 1, dtype=torch.int32, device=device)
    steps = steps * tensor_stride
    a, b, c = torch.meshgrid(steps, steps, steps, indexing="ij")
    if kernel_size**3 % 2 == 1:  # [[x, y, z] for z for y for x]: x varies fastest
        return torch.stack([c, b, a], dim=-1).reshape(-1, 3)
    return torch.stack([a, b, c], dim=-1).reshape(-1, 3)  # [[x, y, z] for x for y for z]: z fastest


def downsample_coords(coords: torch.Tensor, stride: int, tensor_stride: int) -> torch.Tensor:
    """the output coordinates of a strided convolution: torchsparse's `spdownsample` for stride = kernel size."""
    step = stride * tensor_stride
    xyz = torch.div(coords[:, :3], step, rounding_mode="trunc") * step
    batch_first = torch.cat([coords[:, 3:], xyz], dim=1)
    return torch.unique(batch_first, dim=0)[:, [1, 2, 3, 0]].contiguous()


@dataclass(frozen=True)
class CoordinateKeys:
    """exact int64 keys of (x, y, z, batch) coordinates inside a box: `key(c + d) = key(c) + key_of_offset(d)`."""

    low: torch.Tensor  # [4] the box's smallest corner
    extent: torch.Tensor  # [4] its size along each axis

    @staticmethod
    def around(*coords: torch.Tensor, margin: int = 0) -> CoordinateKeys:
        """the box holding every row of `coords`, widened by `margin` on x, y and z."""
        rows = torch.cat([c.reshape(-1, 4) for c in coords]).to(torch.int64)
        pad = torch.tensor([margin, margin, margin, 0], device=rows.device)
        low = rows.min(dim=0).values - pad if len(rows) else -pad
        high = rows.max(dim=0).values + pad if len(rows) else pad
        return CoordinateKeys(low, high - low + 1)

    def __call__(self, coords: torch.Tensor) -> torch.Tensor:
        c = coords.to(torch.int64) - self.low
        ex, ey, ez = self.extent[:3]
        return ((c[..., 3] * ex + c[..., 0]) * ey + c[..., 1]) * ez + c[..., 2]

    def of_offsets(self, offsets: torch.Tensor) -> torch.Tensor:
        d = offsets.to(torch.int64)
        return (d[:, 0] * self.extent[1] + d[:, 1]) * self.extent[2] + d[:, 2]


def find_rows(queries: torch.Tensor, table: torch.Tensor) -> torch.Tensor:
    """the row of `table` [M x 4] holding each coordinate of `queries` [... x 4], -1 where none (the first row of
    duplicates, as torchsparse's hash table keeps the first inserted)."""
    keys = CoordinateKeys.around(queries, table)
    return _search(keys(table), keys(queries))


def _search(table_keys: torch.Tensor, query_keys: torch.Tensor) -> torch.Tensor:
    if not len(table_keys):
        return torch.full_like(query_keys, -1)
    ordered, order = torch.sort(table_keys, stable=True)
    slots = torch.searchsorted(ordered, query_keys).clamp_(max=len(ordered) - 1)
    return torch.where(ordered[slots] == query_keys, order[slots], torch.full_like(query_keys, -1))


@dataclass(frozen=True)
class KernelMap:
    """which input row feeds which output row under each kernel offset: `pairs[k] = (inputs, outputs)` index tensors;
    `identity`: the offset whose pairs map every row to itself (a submanifold convolution's centre), else None."""

    pairs: tuple[tuple[torch.Tensor, torch.Tensor], ...]
    n_in: int
    n_out: int
    identity: int | None = None

    def swapped(self) -> KernelMap:
        """the map of the transposed convolution: the same pairs read the other way round."""
        return KernelMap(tuple((o, i) for i, o in self.pairs), self.n_out, self.n_in, self.identity)


def _first_rows(keys: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """the distinct keys, sorted, and the first row holding each."""
    table, inverse = torch.unique(keys, return_inverse=True)
    rows = torch.arange(len(keys), device=keys.device)
    first = torch.full_like(table, len(keys)).scatter_reduce(0, inverse, rows, "amin")
    return table, first


def build_kernel_map(
    in_coords: torch.Tensor, out_coords: torch.Tensor, kernel_size: int, tensor_stride: int
) -> KernelMap:
    """for each offset, the (input, output) rows with `in_coords[input] = out_coords[output] + offset`.

    Duplicate input coordinates resolve to the first row, as torchsparse's hash table keeps the first inserted."""
    if bool((in_coords[:, :3] % tensor_stride != 0).any()):
        raise ValueError(f"build_kernel_map: input coordinates are not all multiples of their stride {tensor_stride}")
    offsets = kernel_offsets(kernel_size, tensor_stride, in_coords.device)
    keys = CoordinateKeys.around(in_coords, out_coords, margin=int(offsets.abs().max()))
    out_keys, out_rows = torch.sort(keys(out_coords))
    rows = _column_search(keys(in_coords), out_keys, keys, offsets)
    pairs = []
    for k in range(len(offsets)):
        hits = (rows[k] >= 0).nonzero().squeeze(1)
        pairs.append((rows[k, hits], out_rows[hits]))
    same = in_coords is out_coords and len(torch.unique(keys(in_coords))) == len(in_coords)
    centre = len(offsets) // 2 if same and len(offsets) % 2 else None
    return KernelMap(tuple(pairs), len(in_coords), len(out_coords), centre)


def _column_search(
    in_keys: torch.Tensor, out_keys: torch.Tensor, keys: CoordinateKeys, offsets: torch.Tensor
) -> torch.Tensor:
    """[K x N_out] input row (or -1) of each sorted output key plus each offset, one `searchsorted` per (x, y)
    offset: z is the key's fastest axis, so the inputs at z offsets d_0 < d_1 < ... of one output are consecutive
    in the sorted input keys (coordinates are multiples of the stride, the offsets' step), found by walking on from
    the first one's slot."""
    rows = torch.full((len(offsets), len(out_keys)), -1, dtype=torch.int64, device=out_keys.device)
    if not len(in_keys):
        return rows
    table, order = _first_rows(in_keys)
    offset_keys = keys.of_offsets(offsets)
    for column in torch.unique(offsets[:, :2], dim=0):
        ks = ((offsets[:, :2] == column).all(dim=1)).nonzero().squeeze(1)
        ks = ks[torch.argsort(offsets[ks, 2])]
        base = out_keys + offset_keys[ks[0]]
        slots = torch.searchsorted(table, base)
        walked = torch.zeros_like(slots)
        for k in ks.tolist():
            at = (slots + walked).clamp(max=len(table) - 1)
            hit = table[at] == out_keys + offset_keys[k]
            rows[k] = torch.where(hit, order[at], rows[k])
            walked += hit
    return rows


def apply_kernel_map(feats: torch.Tensor, kernel: torch.Tensor, kmap: KernelMap) -> torch.Tensor:
    """[n_in x C_in] -> [n_out x C_out]: gather each offset's input rows, one matmul per offset, one scatter-add."""
    out = feats.new_zeros(kmap.n_out, kernel.shape[-1])
    if kmap.identity is not None:
        out = feats @ kernel[kmap.identity]
    rest = [(k, i, o) for k, (i, o) in enumerate(kmap.pairs) if k != kmap.identity and len(o)]
    if not rest:
        return out
    products = torch.cat([feats.index_select(0, i) @ kernel[k] for k, i, _ in rest])
    targets = torch.cat([o for _, _, o in rest]).unsqueeze(1).expand(-1, kernel.shape[-1])
    return out.scatter_add(0, targets, products)


@dataclass
class SparseVoxels:
    """features on occupied voxels: `feats` [N x C], `coords` [N x 4] int32 (x, y, z, batch) at `stride`.

    `coord_maps` (stride -> coordinates) and `kernel_maps` are shared by every tensor derived from one voxelisation,
    so a transposed convolution finds the coordinates it returns to and maps are built once per forward pass."""

    feats: torch.Tensor
    coords: torch.Tensor
    stride: int = 1
    coord_maps: dict[int, torch.Tensor] = field(default_factory=dict)
    kernel_maps: dict[tuple[int, int, int], KernelMap] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.coords.ndim != 2 or self.coords.shape[1] != 4 or len(self.coords) != len(self.feats):
            raise ValueError(
                f"SparseVoxels: coords must be [N x 4] (x, y, z, batch) with one row per feature row; "
                f"got coords {tuple(self.coords.shape)} and feats {tuple(self.feats.shape)}"
            )
        self.coord_maps.setdefault(self.stride, self.coords)

    def with_feats(self, feats: torch.Tensor) -> SparseVoxels:
        """the same voxels (and shared maps) carrying other features."""
        return SparseVoxels(feats, self.coords, self.stride, self.coord_maps, self.kernel_maps)


def sparse_cat(tensors: list[SparseVoxels]) -> SparseVoxels:
    """features of tensors on the same voxels side by side (torchsparse.cat)."""
    return tensors[0].with_feats(torch.cat([t.feats for t in tensors], dim=1))


class SparseConv3d(nn.Module):
    """torchsparse 2.0's `spnn.Conv3d` (submanifold at stride 1, strided, transposed); the same parameter names and
    shapes (`kernel`, `bias`) and initialisation, so a torchsparse state dict loads as it is."""

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel_size: int = 3,
        stride: int = 1,
        bias: bool = False,
        transposed: bool = False,
    ) -> None:
        super().__init__()
        if stride not in (1, kernel_size):
            raise ValueError(
                f"SparseConv3d: stride {stride} with kernel size {kernel_size}: only stride 1 or stride = kernel "
                "size are defined (torchsparse 2.0's CPU path raises NotImplementedError for the others)"
            )
        self.kernel_size, self.stride, self.transposed = kernel_size, stride, transposed
        volume = kernel_size**3
        shape = (volume, in_channels, out_channels) if volume > 1 else (in_channels, out_channels)
        self.kernel = nn.Parameter(torch.zeros(shape))
        self.bias = nn.Parameter(torch.zeros(out_channels)) if bias else None
        bound = 1 / math.sqrt((out_channels if transposed else in_channels) * volume)
        nn.init.uniform_(self.kernel, -bound, bound)
        if self.bias is not None:
            nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: SparseVoxels) -> SparseVoxels:
        if self.kernel.ndim == 2 and self.stride == 1:
            out = x.with_feats(x.feats @ self.kernel)
        elif self.transposed:
            out = self._transposed(x)
        else:
            out = self._forward(x)
        if self.bias is not None:
            out.feats = out.feats + self.bias
        return out

    def _forward(self, x: SparseVoxels) -> SparseVoxels:
        stride = x.stride * self.stride
        if stride not in x.coord_maps:
            x.coord_maps[stride] = downsample_coords(x.coords, self.stride, x.stride)
        coords = x.coord_maps[stride]
        kmap = self._kernel_map(x, x.coords, coords, x.stride)
        feats = apply_kernel_map(x.feats, self._kernel_3d(), kmap)
        return SparseVoxels(feats, coords, stride, x.coord_maps, x.kernel_maps)

    def _transposed(self, x: SparseVoxels) -> SparseVoxels:
        fine = x.stride // self.stride
        if fine not in x.coord_maps:
            raise ValueError(
                f"SparseConv3d (transposed): no coordinates at stride {fine} to return to; a transposed "
                "convolution undoes a strided one applied earlier to the same voxelisation"
            )
        coords = x.coord_maps[fine]
        kmap = self._kernel_map(x, coords, x.coords, fine).swapped()
        feats = apply_kernel_map(x.feats, self._kernel_3d(), kmap)
        return SparseVoxels(feats, coords, fine, x.coord_maps, x.kernel_maps)

    def _kernel_map(self, x: SparseVoxels, fine: torch.Tensor, coarse: torch.Tensor, fine_stride: int) -> KernelMap:
        key = (fine_stride, self.kernel_size, self.stride)
        if key not in x.kernel_maps:
            x.kernel_maps[key] = build_kernel_map(fine, coarse, self.kernel_size, fine_stride)
        return x.kernel_maps[key]

    def _kernel_3d(self) -> torch.Tensor:
        return self.kernel if self.kernel.ndim == 3 else self.kernel.unsqueeze(0)


class SparseBatchNorm(nn.BatchNorm1d):
    """BatchNorm over the voxels' features (torchsparse's `spnn.BatchNorm`; the same state dict)."""

    def forward(self, x: SparseVoxels) -> SparseVoxels:  # type: ignore[override]
        return x.with_feats(super().forward(x.feats))


class SparseReLU(nn.ReLU):
    """ReLU on the voxels' features (torchsparse's `spnn.ReLU`)."""

    def forward(self, x: SparseVoxels) -> SparseVoxels:  # type: ignore[override]
        return x.with_feats(super().forward(x.feats))
