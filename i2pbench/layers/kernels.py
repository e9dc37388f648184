"""Compiled point-grouping kernels for CPU tensors: farthest point sampling, ball query and 3-nearest neighbours.

Why: PointNet++'s grouping is a sequential loop (FPS) and a radius search, which torch can only express as thousands
of small kernels (FPS) or a dense [centres x points] distance matrix (ball query). At the paper's size they took
~1.2 s of a ~1.8 s encoder3d on this CPU while counting no FLOPs. FPS and the ball query are compiled with numba (no
registry package gives FPS with a chosen start that is faster than the torch loop: fpsample's exact `fps_sampling`
ran at the torch loop's speed here and its bucket variants do not honour `start_idx`; torch-cluster and pytorch3d
have no wheels); 3-NN is SciPy's cKDTree. The torch versions in pointnet2.py stay the reference (and the CUDA path);
tests compare both.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.spatial import cKDTree

REVISION = 1  # bump when an output of this module changes for the same inputs (see i2pbench.layers)


@numba.njit(cache=True, nogil=True)
def _fps(x: np.ndarray, y: np.ndarray, z: np.ndarray, n: int, start: int, out: np.ndarray) -> None:
    """the reference's loop, point by point: same float32 squares and sums, first maximum on ties.

    No fused multiply-add (no `fastmath`): each square is rounded, then summed x + y, then + z, as the PointNet++
    code the official sizes follow computes `sum((xyz - centroid) ** 2, -1)`; a fused sum rounds differently and
    can turn their strict maximum into a tie (or back), which moves a centroid."""
    dist = np.full(x.shape[0], np.inf, dtype=np.float32)
    far = start
    for i in range(n):
        out[i] = far
        cx, cy, cz = x[far], y[far], z[far]
        for j in range(x.shape[0]):
            dx, dy, dz = x[j] - cx, y[j] - cy, z[j] - cz
            d = dx * dx + dy * dy
            d = d + dz * dz
            dist[j] = min(dist[j], d)
        far = np.argmax(dist)


@numba.njit(cache=True, nogil=True)
def _fps_cells(
    x: np.ndarray, y: np.ndarray, z: np.ndarray, n: int, start: int, out: np.ndarray, per_cell: int = 32
) -> None:
    """`_fps`'s indices, skipping the points a new centroid cannot bring closer.

    Points are binned in grid cells of about `per_cell` points. A cell keeps the largest distance of its points so
    far and the first index holding it; a cell whose bounding box lies farther from the new centroid than that
    largest distance (with a margin above float32's rounding of a squared distance) keeps every distance, so it is
    skipped, and the argmax is taken over the cells (the largest, then the lowest index: np.argmax's rule). The
    distances that are computed are computed as `_fps` does. 137 -> 15 ms for the official EdgeRegNet's 5,120 of
    20,480 points here.
    """
    num = x.shape[0]
    lo = np.array([x.min(), y.min(), z.min()], np.float64)
    extent = np.array([x.max(), y.max(), z.max()], np.float64) - lo
    widest = max(extent.max(), 1e-30)
    for a in range(3):
        extent[a] = max(extent[a], widest * 1e-3)  # a flat or empty axis still gets one layer of cells
    side = (extent[0] * extent[1] * extent[2] / max(num // per_cell, 1)) ** (1 / 3)
    dims = np.empty(3, np.int64)
    for a in range(3):
        dims[a] = min(max(int(extent[a] / side), 1), 1024)
    keys = np.empty(num, np.int64)
    for j in range(num):
        key = 0
        for a, value in enumerate((x[j], y[j], z[j])):
            key = key * dims[a] + min(int((value - lo[a]) / extent[a] * dims[a]), dims[a] - 1)
        keys[j] = key
    order = np.argsort(keys, kind="mergesort")  # stable: each cell's points in ascending index order
    xs, ys, zs, sorted_keys = x[order], y[order], z[order], keys[order]
    starts = [0]
    for q in range(1, num):
        if sorted_keys[q] != sorted_keys[q - 1]:
            starts.append(q)
    starts.append(num)
    first = np.array(starts, np.int64)
    cells = len(first) - 1
    box = np.empty((cells, 6))
    for c in range(cells):
        b0, b1 = first[c], first[c + 1]
        box[c, 0], box[c, 1], box[c, 2] = xs[b0:b1].min(), ys[b0:b1].min(), zs[b0:b1].min()
        box[c, 3], box[c, 4], box[c, 5] = xs[b0:b1].max(), ys[b0:b1].max(), zs[b0:b1].max()
    dist = np.full(num, np.inf, dtype=np.float32)
    cell_max = np.full(cells, np.inf, dtype=np.float32)
    cell_arg = order[first[:-1]].copy()
    far = start
    for i in range(n):
        out[i] = far
        cx, cy, cz = x[far], y[far], z[far]
        for c in range(cells):
            gx = max(box[c, 0] - cx, cx - box[c, 3], 0.0)
            gy = max(box[c, 1] - cy, cy - box[c, 4], 0.0)
            gz = max(box[c, 2] - cz, cz - box[c, 5], 0.0)
            bound = gx * gx + gy * gy + gz * gz  # float64: at most any point's squared distance
            if bound > 1e-30 and bound * (1 - 1e-6) > cell_max[c]:
                continue
            best, arg = np.float32(-np.inf), -1
            for q in range(first[c], first[c + 1]):
                dx, dy, dz = xs[q] - cx, ys[q] - cy, zs[q] - cz
                d = dx * dx + dy * dy
                d = d + dz * dz
                d = min(dist[q], d)
                dist[q] = d
                if d > best:
                    best, arg = d, order[q]
            cell_max[c], cell_arg[c] = best, arg
        far, top = cell_arg[0], cell_max[0]
        for c in range(1, cells):
            if cell_max[c] > top or (cell_max[c] == top and cell_arg[c] < far):
                far, top = cell_arg[c], cell_max[c]


def farthest_point_sampling(xyz: np.ndarray, n: int, start: int = 0) -> np.ndarray:
    """xyz [B x N x 3] float32 -> [B x n] int64 indices, as pointnet2's torch `farthest_point_sampling` (a cloud with
    a non-finite coordinate, whose cells are undefined, by the plain loop)."""
    out = np.empty((len(xyz), n), np.int64)
    for b, cloud in enumerate(xyz):
        x, y, z = (np.ascontiguousarray(c, np.float32) for c in cloud.T)
        (_fps_cells if len(x) and np.isfinite(cloud).all() else _fps)(x, y, z, n, start, out[b])
    return out


@numba.njit(cache=True, nogil=True)
def _cell_keys(xyz: np.ndarray, lo: np.ndarray, size: float, dims: np.ndarray) -> np.ndarray:
    """each point's cell of a grid with cells of `size` from `lo`, flattened (x-major)."""
    keys = np.empty(xyz.shape[0], np.int64)
    for i in range(xyz.shape[0]):
        key = 0
        for a in range(3):
            cell = min(max(int(np.floor((xyz[i, a] - lo[a]) / size)), 0), dims[a] - 1)
            key = key * dims[a] + cell
        keys[i] = key
    return keys


@numba.njit(cache=True, nogil=True)
def _ball_query(
    xyz: np.ndarray, centres: np.ndarray, radius: float, k: int, out: np.ndarray, sort_below: float = 4.0
) -> int:
    """fills out [C x k] with the first k indices inside each ball (ascending, padded with the first); returns the
    number of empty balls.

    Points are binned in cells of side ~radius, each cell's points kept in ascending index order. A ball whose 27
    neighbouring cells hold few points (at most `sort_below` x k) tests them all and sorts the indices inside; a
    ball in a dense region reads the cells merged in index order and stops at the k-th point inside. Both give the
    same ball, each the faster where it is taken (one thread, the official EdgeRegNet's SA1 + SA2 balls against the
    merge alone: 111-124 -> 89-104 ms on the reference KITTI frame, 137-144 -> 63-64 ms on the synthetic KITTI-sized
    one; sort_below tuned over 0-16 on both).
    """
    size = radius * (1 + 1e-5)  # a point within radius is at most one cell away despite rounding in the division
    lo = np.empty(3)
    dims = np.empty(3, np.int64)
    for a in range(3):
        lo[a] = xyz[:, a].min()
        dims[a] = int(np.floor((xyz[:, a].max() - lo[a]) / size)) + 1
    keys = _cell_keys(xyz, lo, size, dims)
    order = np.argsort(keys, kind="mergesort")  # stable: each cell's points stay in ascending index order
    sorted_keys = keys[order]
    r2 = np.float32(radius) * np.float32(radius)
    heads, ends, home = np.empty(27, np.int64), np.empty(27, np.int64), np.empty(3, np.int64)
    inside = np.empty(xyz.shape[0], np.int64)
    empty = 0
    for c in range(centres.shape[0]):
        for a in range(3):
            home[a] = int(np.floor((centres[c, a] - lo[a]) / size))
        cells, candidates = 0, 0
        for i in range(max(home[0] - 1, 0), min(home[0] + 2, dims[0])):
            for j in range(max(home[1] - 1, 0), min(home[1] + 2, dims[1])):
                for m in range(max(home[2] - 1, 0), min(home[2] + 2, dims[2])):
                    key = (i * dims[1] + j) * dims[2] + m
                    heads[cells] = np.searchsorted(sorted_keys, key, side="left")
                    ends[cells] = np.searchsorted(sorted_keys, key, side="right")
                    candidates += ends[cells] - heads[cells]
                    cells += heads[cells] < ends[cells]
        count = 0
        if candidates <= sort_below * k:
            for q in range(cells):
                for h in range(heads[q], ends[q]):
                    point = order[h]
                    if _inside(xyz, point, centres, c, r2):
                        inside[count] = point
                        count += 1
            if count > 0:
                first = np.sort(inside[:count])
                count = min(count, k)
                out[c, :count] = first[:count]
        else:
            while count < k:
                best, point = -1, xyz.shape[0]
                for q in range(cells):
                    if heads[q] < ends[q] and order[heads[q]] < point:
                        best, point = q, order[heads[q]]
                if best < 0:
                    break
                heads[best] += 1
                if _inside(xyz, point, centres, c, r2):
                    out[c, count] = point
                    count += 1
        if count == 0:
            empty += 1
        else:
            out[c, count:] = out[c, 0]
    return empty


@numba.njit(cache=True, nogil=True, inline="always")
def _inside(xyz: np.ndarray, point: int, centres: np.ndarray, c: int, r2: np.float32) -> bool:
    """whether xyz[point] lies within the ball around centres[c], squared distance in float32, x + y then + z."""
    dx = xyz[point, 0] - centres[c, 0]
    dy = xyz[point, 1] - centres[c, 1]
    dz = xyz[point, 2] - centres[c, 2]
    return dx * dx + dy * dy + dz * dz <= r2


def ball_query(xyz: np.ndarray, centres: np.ndarray, radius: float, nsample: int) -> np.ndarray:
    """first `nsample` indices (ascending) of xyz [B x N x 3] within radius of each centre [B x C x 3] -> [B x C x k],
    balls with fewer points repeating their first; a ball may differ from the torch reference only by a point whose
    distance to the centre is within float rounding of the radius (the two compute it in different orders)."""
    out = np.empty((len(xyz), centres.shape[1], nsample), np.int64)
    for b in range(len(xyz)):
        cloud = np.ascontiguousarray(xyz[b], np.float32)
        empty = _ball_query(cloud, np.ascontiguousarray(centres[b], np.float32), radius, nsample, out[b])
        if empty:
            raise ValueError(f"ball query: {empty} ball(s) of radius {radius} hold no point (centres not from xyz?)")
    return out


def three_nn(xyz: np.ndarray, known: np.ndarray) -> np.ndarray:
    """indices of the 3 nearest of known [B x K x 3] for each xyz [B x M x 3], nearest first -> [B x M x min(3, K)]."""
    k = min(3, known.shape[1])
    out = np.empty((len(xyz), xyz.shape[1], k), np.int64)
    for b in range(len(xyz)):
        if xyz.shape[1] and k:
            out[b] = cKDTree(known[b]).query(xyz[b], k=list(range(1, k + 1)))[1]
    return out
