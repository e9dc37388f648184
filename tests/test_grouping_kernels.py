"""The compiled grouping kernels (FPS, ball query, 3-NN) give the torch reference's indices on real KITTI scans, and
EdgeRegNet's 3D descriptors do not change when they replace it (speed: benchmarks/roofline.py)."""

import numpy as np
import pytest
import torch
from i2pbench_edgeregnet.configs import CPU
from i2pbench_edgeregnet.pointnet2 import PointNet2Encoder

from i2pbench.data.kitti import read_points
from i2pbench.layers import pointnet2
from i2pbench.layers.pointnet2 import gather, group, normalize_points

RELATIVE_ROUNDING = 1e-5  # float32 sums in two orders differ by ~1e-7 relative; 100x that is still a tie


@pytest.fixture(params=["04", "26"])
def real_cloud(request, shared_data) -> torch.Tensor:
    """a real scan as the encoder sees it: a seeded 8,192-point subset, normalised -> [1 x N x 3] float32."""
    scan = sorted((shared_data / "kitti_real" / "sequences" / request.param / "velodyne").glob("*.bin"))[0]
    points = read_points(scan)[:, :3]
    subset = points[np.random.default_rng(0).choice(len(points), 8192, replace=False)]
    xyz = torch.from_numpy(np.ascontiguousarray(subset, np.float32))
    return normalize_points(xyz, xyz)[None]


def min_sq_distances(xyz: np.ndarray, chosen: np.ndarray) -> np.ndarray:
    """each point's float64 squared distance to its nearest chosen point."""
    dist = np.full(len(xyz), np.inf)
    for c in chosen:
        dist = np.minimum(dist, ((xyz - xyz[c]) ** 2).sum(1))
    return dist


def test_fps_gives_the_reference_indices_or_parts_at_a_float_tie(real_cloud):
    compiled = pointnet2.farthest_point_sampling(real_cloud, 2048)[0].numpy()
    reference = pointnet2.farthest_point_sampling_torch(real_cloud, 2048)[0].numpy()
    assert compiled[0] == reference[0] == 0 and len(set(compiled.tolist())) == 2048
    differ = np.flatnonzero(compiled != reference)
    if len(differ):  # two points equally far up to float rounding: either is the farthest, and the paths part there
        step = differ[0]
        dist = min_sq_distances(real_cloud[0].double().numpy(), reference[:step])
        a, b = dist[reference[step]], dist[compiled[step]]
        assert abs(a - b) <= RELATIVE_ROUNDING * max(a, b), f"step {step}: {a} vs {b} is no tie"


def test_fps_on_exactly_representable_points_is_identical_including_ties():
    # integer coordinates: every squared distance is exact in float32, so any order of the sums gives the same
    # value and ties (many on a grid) must go to the first index, as torch.argmax does
    grid = np.stack(np.meshgrid(np.arange(12), np.arange(10), np.arange(4), indexing="ij"), -1).reshape(-1, 3)
    xyz = torch.from_numpy(grid[np.random.default_rng(3).permutation(len(grid))].astype(np.float32))[None]
    np.testing.assert_array_equal(
        pointnet2.farthest_point_sampling(xyz, 200, start=5), pointnet2.farthest_point_sampling_torch(xyz, 200, start=5)
    )


def test_fps_skipping_cells_gives_the_plain_loops_indices(real_cloud):
    """the compiled FPS skips the grid cells a new centroid cannot bring closer: the indices of the plain loop
    computing every distance, on a real scan (cells of 8 and of 32 points) and past the last point (repeats)."""
    from i2pbench.layers import kernels

    x, y, z = (np.ascontiguousarray(c) for c in real_cloud[0].numpy().T)
    plain, skipping = np.empty(3000, np.int64), np.empty(3000, np.int64)
    kernels._fps(x, y, z, 3000, 11, plain)
    for per_cell in (8, 32):
        kernels._fps_cells(x, y, z, 3000, 11, skipping, per_cell)
        np.testing.assert_array_equal(skipping, plain)
    tiny = np.float32([0.0, 1.0, 1.0, 3.0])
    kernels._fps(tiny, tiny, tiny, 6, 2, plain[:6])
    kernels._fps_cells(tiny, tiny, tiny, 6, 2, skipping[:6], 1)
    np.testing.assert_array_equal(skipping[:6], plain[:6])  # a duplicate point and repeats once all are taken


def test_ball_query_gives_the_reference_balls_except_at_the_radius_within_rounding(real_cloud):
    centres = gather(real_cloud, pointnet2.farthest_point_sampling(real_cloud, 2048))
    compiled = pointnet2.ball_query(real_cloud, centres, 0.1, 32)[0].numpy()
    reference = pointnet2.ball_query_torch(real_cloud, centres, 0.1, 32)[0].numpy()
    sq = ((real_cloud[0].double().numpy()[None] - centres[0].double().numpy()[:, None]) ** 2).sum(-1)
    # the reference's |c|^2 - 2 c.x + |x|^2 rounds to ~1e-7 of |c|^2 + |x|^2 (up to 2 on a normalised cloud)
    # and only points up to a full ball's last index can change it
    full = (reference != reference[:, :1]).sum(1) == 31  # balls holding at least 32 points
    last = np.where(full, reference.max(1), len(sq[0]))
    on_the_rim = ((np.abs(sq - 0.1**2) <= 4e-6) & (np.arange(len(sq[0]))[None] <= last[:, None])).any(1)
    np.testing.assert_array_equal(compiled[~on_the_rim], reference[~on_the_rim])
    assert on_the_rim.mean() < 0.1
    assert 0.2 < full.mean() < 1.0  # the case exercises both full and padded balls


def test_three_nn_gives_the_reference_neighbours_up_to_ties(real_cloud):
    known = gather(real_cloud, pointnet2.farthest_point_sampling(real_cloud, 512))
    queries = real_cloud[:, ::4]
    compiled = pointnet2.three_nn(queries, known)[0].numpy()
    reference = pointnet2.three_nn_torch(queries, known)[0].numpy()
    q, k = queries[0].double().numpy(), known[0].double().numpy()
    for row in np.flatnonzero((compiled != reference).any(1)):  # only where two neighbours are equally near
        d_compiled = np.linalg.norm(k[compiled[row]] - q[row], axis=1)
        d_reference = np.linalg.norm(k[reference[row]] - q[row], axis=1)
        np.testing.assert_allclose(d_compiled, d_reference, rtol=RELATIVE_ROUNDING, atol=1e-9)
    assert (compiled == reference).all(1).mean() > 0.99


def test_descriptors_are_unchanged_by_the_compiled_grouping(real_cloud, monkeypatch):
    torch.manual_seed(0)
    encoder = PointNet2Encoder(CPU["encoder3d"]).eval()
    edges = real_cloud[:, :1500]
    compiled = group(real_cloud, edges, encoder.conf)
    monkeypatch.setattr(pointnet2, "ball_query", pointnet2.ball_query_torch)
    monkeypatch.setattr(pointnet2, "three_nn", pointnet2.three_nn_torch)
    fps = iter([compiled["fps1"], compiled["fps2"]])  # FPS parity (ties aside) is the test above; same centres here
    monkeypatch.setattr(pointnet2, "farthest_point_sampling", lambda *args: next(fps))
    reference = group(real_cloud, edges, encoder.conf)
    inputs = {"xyz": real_cloud, "reflectance": torch.ones_like(real_cloud[..., :1]), "edge_xyz": edges}
    inputs["edge_reflectance"] = inputs["reflectance"][:, :1500]
    with torch.no_grad():
        ours, theirs = encoder.forward({**inputs, **compiled}), encoder.forward({**inputs, **reference})
    torch.testing.assert_close(ours, theirs, rtol=0, atol=1e-5)
