"""i2pbench.layers.sparse and point_voxel: torchsparse 2.0's sparse convolution and SPVCNN's point/voxel conversions,
proven against a dense `conv3d` / `conv_transpose3d` on the same voxels and against hand-worked small cases."""

import pytest
import torch
import torch.nn.functional as F

from i2pbench.layers.point_voxel import SparsePoints, initial_voxelize, point_to_voxel, voxel_to_point
from i2pbench.layers.sparse import (
    SparseBatchNorm,
    SparseConv3d,
    SparseVoxels,
    build_kernel_map,
    downsample_coords,
    kernel_offsets,
    sparse_cat,
    voxel_hash,
)

GRID = 8  # voxels per side of the random clouds


def fnv(coords: tuple[int, int, int, int]) -> int:
    """torchsparse's hash in Python integers: FNV-1a 64 over the uint32 bits of x, y, z, batch, folded to 60 bits."""
    h = 14695981039346656037
    for c in coords:
        h = ((h ^ (c & 0xFFFFFFFF)) * 1099511628211) % (1 << 64)
    return (h >> 60) ^ (h & ((1 << 60) - 1))


def random_voxels(n: int, channels: int, stride: int = 1, batches: int = 2, seed: int = 0) -> SparseVoxels:
    """n distinct voxels (multiples of `stride`) in a GRID^3 box per batch, float64 features."""
    g = torch.Generator().manual_seed(seed)
    cells = torch.randperm(batches * GRID**3, generator=g)[:n]
    b, rest = cells // GRID**3, cells % GRID**3
    xyz = torch.stack([rest // GRID**2, rest // GRID % GRID, rest % GRID], dim=1) * stride
    coords = torch.cat([xyz, b.unsqueeze(1)], dim=1).to(torch.int32)
    return SparseVoxels(torch.randn(n, channels, generator=g, dtype=torch.float64), coords, stride)


def dense(x: SparseVoxels, batches: int = 2, size: int = GRID) -> torch.Tensor:
    """[B x C x X x Y x Z] grid in units of x's stride, zeros where no voxel."""
    grid = torch.zeros(batches, x.feats.shape[1], size, size, size, dtype=x.feats.dtype)
    xyz = (x.coords[:, :3] // x.stride).long()
    grid[x.coords[:, 3].long(), :, xyz[:, 0], xyz[:, 1], xyz[:, 2]] = x.feats
    return grid


def at(grid: torch.Tensor, coords: torch.Tensor, stride: int) -> torch.Tensor:
    xyz = (coords[:, :3] // stride).long()
    return grid[coords[:, 3].long(), :, xyz[:, 0], xyz[:, 1], xyz[:, 2]]


def dense_kernel(kernel: torch.Tensor, size: int, transposed: bool = False) -> torch.Tensor:
    """torchsparse's [K^3 x C_in x C_out] kernel as conv3d's [C_out x C_in x K x K x K] weight (conv_transpose3d's
    [C_in x C_out x K x K x K]), placing each slice at its offset from `kernel_offsets`."""
    offsets = kernel_offsets(size).long() - (-size // 2 + 1)
    c_in, c_out = kernel.shape[1:]
    weight = torch.zeros((c_in, c_out) if transposed else (c_out, c_in), dtype=kernel.dtype).repeat(
        size, size, size, 1, 1
    )
    for k, (i, j, m) in enumerate(offsets.tolist()):
        weight[i, j, m] = kernel[k] if transposed else kernel[k].T
    return weight.permute(3, 4, 0, 1, 2)


def conv(c_in: int, c_out: int, size: int, stride: int = 1, transposed: bool = False) -> SparseConv3d:
    torch.manual_seed(1)
    return SparseConv3d(c_in, c_out, size, stride, transposed=transposed).double()


def test_voxel_hash_is_torchsparse_fnv_bit_for_bit():
    rows = [(0, 0, 0, 0), (1, 2, 3, 0), (-1, 5, 70000, 3), (2**31 - 1, -(2**31), 7, 1)]
    got = voxel_hash(torch.tensor(rows, dtype=torch.int32)).tolist()
    assert got == [fnv(r) for r in rows]
    assert all(0 <= h < 2**60 for h in got)


def test_kernel_offsets_follow_torchsparse_order():
    three = kernel_offsets(3).tolist()
    assert three[:3] == [[-1, -1, -1], [0, -1, -1], [1, -1, -1]]  # odd volume: x fastest
    assert three[3] == [-1, 0, -1] and three[9] == [-1, -1, 0]
    assert three[13] == [0, 0, 0] and three[26] == [1, 1, 1]
    two = kernel_offsets(2, tensor_stride=4).tolist()  # even volume: z fastest, multiples of the input stride
    assert two == [[0, 0, 0], [0, 0, 4], [0, 4, 0], [0, 4, 4], [4, 0, 0], [4, 0, 4], [4, 4, 0], [4, 4, 4]]


def test_two_voxels_by_hand():
    """voxels at (0,0,0) = 1 and (1,0,0) = 10, kernel slice k = k + 1: each output adds its own value times 14
    (offset (0,0,0) is slot 13) and its neighbour's: +x is slot 14 (15), -x is slot 12 (13)."""
    x = SparseVoxels(torch.tensor([[1.0], [10.0]]), torch.tensor([[0, 0, 0, 0], [1, 0, 0, 0]], dtype=torch.int32))
    layer = SparseConv3d(1, 1, 3)
    with torch.no_grad():
        layer.kernel.copy_(torch.arange(1.0, 28.0).view(27, 1, 1))
    y = layer(x)
    assert y.feats.squeeze(1).tolist() == [14 * 1 + 15 * 10, 14 * 10 + 13 * 1]
    assert torch.equal(y.coords, x.coords)
    assert x.kernel_maps[(1, 3, 1)].identity == 13  # the centre: every voxel to itself, one plain matmul


@pytest.mark.parametrize("stride", [1, 2])
def test_submanifold_equals_dense_conv3d(stride):
    x = random_voxels(300, 5, stride=stride)
    layer = conv(5, 7, 3)
    y = layer(x)
    ref = F.conv3d(dense(x), dense_kernel(layer.kernel.detach(), 3), padding=1)
    assert torch.equal(y.coords, x.coords) and y.stride == stride
    torch.testing.assert_close(y.feats, at(ref, x.coords, stride), rtol=1e-12, atol=1e-12)


def test_strided_equals_dense_conv3d_and_sorts_outputs():
    x = random_voxels(300, 4)
    layer = conv(4, 6, 2, stride=2)
    y = layer(x)
    expected = torch.unique(torch.cat([x.coords[:, 3:], x.coords[:, :3] // 2 * 2], dim=1), dim=0)[:, [1, 2, 3, 0]]
    assert torch.equal(y.coords, expected) and y.stride == 2
    ref = F.conv3d(dense(x), dense_kernel(layer.kernel.detach(), 2), stride=2)
    torch.testing.assert_close(y.feats, at(ref, y.coords, 2), rtol=1e-12, atol=1e-12)


def test_transposed_returns_to_the_fine_voxels_as_conv_transpose3d():
    x = random_voxels(300, 4)
    coarse = conv(4, 6, 2, stride=2)(x)
    up = conv(6, 3, 2, stride=2, transposed=True)
    y = up(coarse)
    assert torch.equal(y.coords, x.coords) and y.stride == 1
    ref = F.conv_transpose3d(dense(coarse, size=GRID // 2), dense_kernel(up.kernel.detach(), 2, True), stride=2)
    torch.testing.assert_close(y.feats, at(ref, x.coords, 1), rtol=1e-12, atol=1e-12)


def test_gradients_equal_the_dense_convolutions():
    x = random_voxels(200, 3)
    x.feats.requires_grad_(True)
    layer = conv(3, 4, 3)
    weights = torch.randn(200, 4, dtype=torch.float64)
    (layer(x).feats * weights).sum().backward()

    feats = x.feats.detach().clone().requires_grad_(True)
    kernel = layer.kernel.detach().clone().requires_grad_(True)
    out = at(F.conv3d(dense(x.with_feats(feats)), dense_kernel(kernel, 3), padding=1), x.coords, 1)
    (out * weights).sum().backward()
    torch.testing.assert_close(x.feats.grad, feats.grad, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(layer.kernel.grad, kernel.grad, rtol=1e-12, atol=1e-12)


def test_pointwise_kernel_is_a_matmul_and_keeps_torchsparse_shape():
    x = random_voxels(50, 3)
    layer = conv(3, 2, 1)
    assert layer.kernel.shape == (3, 2)
    torch.testing.assert_close(layer(x).feats, x.feats @ layer.kernel, rtol=0, atol=0)


def test_negative_coordinates_truncate_towards_zero_as_torchsparse():
    """(-1,0,0) goes to output (0,0,0) (trunc, not floor), where it is offset -1: outside the [0, 1] kernel, so it
    contributes nothing; (1,0,0) does, through slot 4 (offset (1,0,0), z fastest)."""
    coords = torch.tensor([[-1, 0, 0, 0], [1, 0, 0, 0]], dtype=torch.int32)
    assert downsample_coords(coords, 2, 1).tolist() == [[0, 0, 0, 0]]
    layer = SparseConv3d(1, 1, 2, stride=2)
    with torch.no_grad():
        layer.kernel.copy_(torch.arange(1.0, 9.0).view(8, 1, 1))
    y = layer(SparseVoxels(torch.tensor([[3.0], [7.0]]), coords))
    assert y.feats.tolist() == [[5 * 7.0]]


def test_kernel_map_takes_the_first_of_duplicate_inputs():
    coords = torch.tensor([[0, 0, 0, 0], [0, 0, 0, 0]], dtype=torch.int32)
    kmap = build_kernel_map(coords, coords[:1], 3, 1)
    assert [i.tolist() for i, _ in kmap.pairs if len(i)] == [[0]]


def test_batchnorm_and_cat_keep_the_voxels():
    x = random_voxels(40, 3)
    norm = SparseBatchNorm(3).double().eval()
    assert torch.equal(norm(x).coords, x.coords)
    both = sparse_cat([x, x.with_feats(2 * x.feats)])
    assert both.feats.shape == (40, 6) and torch.equal(both.feats[:, 3:], 2 * x.feats)


def test_bad_stride_and_missing_fine_voxels_are_refused():
    with pytest.raises(ValueError, match="stride 2 with kernel size 3"):
        SparseConv3d(1, 1, 3, stride=2)
    x = random_voxels(10, 1).with_feats(torch.zeros(10, 1))
    orphan = SparseVoxels(x.feats, x.coords * 2, 2)
    with pytest.raises(ValueError, match="no coordinates at stride 1"):
        SparseConv3d(1, 1, 2, stride=2, transposed=True)(orphan)
    with pytest.raises(ValueError, match=r"\[N x 4\]"):
        SparseVoxels(torch.zeros(3, 1), torch.zeros(3, 3, dtype=torch.int32))


def test_initial_voxelize_averages_and_orders_by_hash():
    coords = torch.tensor([[0.2, 0.1, 0.0, 0], [0.9, 0.5, 0.5, 0], [3.5, 0.0, 0.0, 0], [0.5, 0.5, 0.5, 1]])
    feats = torch.tensor([[1.0], [3.0], [10.0], [7.0]])
    points, voxels = initial_voxelize(SparsePoints(feats, coords), 0.05, 0.05)
    cells = [(0, 0, 0, 0), (3, 0, 0, 0), (0, 0, 0, 1)]
    order = sorted(range(3), key=lambda i: fnv(cells[i]))
    assert voxels.coords.tolist() == [list(cells[i]) for i in order]
    means = {(0, 0, 0, 0): 2.0, (3, 0, 0, 0): 10.0, (0, 0, 0, 1): 7.0}
    assert voxels.feats.squeeze(1).tolist() == [means[cells[i]] for i in order]
    assert point_to_voxel(voxels, points).feats.squeeze(1).tolist() == [means[cells[i]] for i in order]


def test_voxel_to_point_is_trilinear_and_renormalises_missing_corners():
    """corner features f = x + 10 y + 100 z: a linear function, so interpolation is exact at (0.25, 0.5, 0.75)."""
    corners = kernel_offsets(2)
    coords = torch.cat([corners, torch.zeros(8, 1, dtype=torch.int32)], dim=1)
    feats = (corners.double() @ torch.tensor([1.0, 10.0, 100.0], dtype=torch.float64)).unsqueeze(1)
    point = SparsePoints(torch.zeros(1, 1), torch.tensor([[0.25, 0.5, 0.75, 0.0]], dtype=torch.float64))
    got = voxel_to_point(SparseVoxels(feats, coords), point).feats.item()
    assert got == pytest.approx(80.25 / (1 + 1e-8), rel=1e-12)
    # only the (0,0,0) and (1,0,0) corners present: weights 0.75 * 0.5 * 0.25 and 0.25 * 0.5 * 0.25 -> 3:1
    two = SparseVoxels(feats[[0, 4]], coords[[0, 4]])
    got = voxel_to_point(two, SparsePoints(torch.zeros(1, 1), point.coords)).feats.item()
    assert got == pytest.approx((3 * 0.0 + 1 * 1.0) / 4 * 0.125 / (0.125 + 1e-8), rel=1e-12)


def test_kernel_map_of_runs_along_z_with_gaps_and_duplicates():
    """the column search walks along z: a column with a gap (z = 0, 2, 3) and a duplicated voxel still finds each
    neighbour of (0,0,1) and (0,0,2) once, duplicates at their first row."""
    coords = torch.tensor([[0, 0, 0, 0], [0, 0, 2, 0], [0, 0, 3, 0], [0, 0, 2, 0]], dtype=torch.int32)
    out = torch.tensor([[0, 0, 1, 0], [0, 0, 2, 0]], dtype=torch.int32)
    kmap = build_kernel_map(coords, out, 3, 1)
    z_pairs = {dz: (kmap.pairs[k][0].tolist(), kmap.pairs[k][1].tolist()) for dz, k in ((-1, 4), (0, 13), (1, 22))}
    assert z_pairs == {-1: ([0], [0]), 0: ([1], [1]), 1: ([1, 2], [0, 1])}
    assert sum(len(o) for _, o in kmap.pairs) == 4 and kmap.identity is None
    with pytest.raises(ValueError, match="multiples of their stride 2"):
        build_kernel_map(coords, out, 3, 2)
