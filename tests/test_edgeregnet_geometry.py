"""EdgeRegNet's geometric building blocks against brute force and hand-worked values."""

import numpy as np
import pytest
import torch

from i2pbench.geometry.transforms import make_transform, rot_z
from i2pbench.layers.pointnet2 import (
    ball_query,
    ball_query_torch,
    farthest_point_sampling,
    farthest_point_sampling_torch,
    interpolate,
    normalize_points,
    three_nn,
    three_nn_torch,
)
from i2pbench.layers.positions import centred_pixels
from i2pbench.layers.sampling import sample_descriptors


def coordinate_map(hc: int, wc: int) -> torch.Tensor:
    """[1 x 2 x Hc x Wc]: channel 0 holds each cell's column j, channel 1 its row i."""
    i, j = torch.meshgrid(torch.arange(hc, dtype=torch.float32), torch.arange(wc, dtype=torch.float32), indexing="ij")
    return torch.stack([j, i])[None]


def test_sampling_at_cell_centres_returns_the_cell():
    # cell (i, j) pools pixels [8j, 8j + 8) x [8i, 8i + 8): its centre is pixel (8j + 3.5, 8i + 3.5)
    fmap = coordinate_map(5, 7)
    uv = torch.tensor([[3.5, 3.5], [8 * 6 + 3.5, 8 * 4 + 3.5], [8 * 2 + 3.5, 8 * 1 + 3.5]])
    expected = torch.tensor([[0.0, 0.0], [6.0, 4.0], [2.0, 1.0]])
    torch.testing.assert_close(sample_descriptors(fmap, uv[None], 8)[0], expected)


def test_sampling_between_centres_is_linear_and_clamped_at_the_border():
    fmap = coordinate_map(5, 7)
    uv = torch.tensor([[12.0, 20.0], [0.0, 0.0], [60.0, 39.0]])  # interior; left of first centre; right/below last
    expected = torch.tensor([[(12 - 3.5) / 8, (20 - 3.5) / 8], [0.0, 0.0], [6.0, 4.0]])
    torch.testing.assert_close(sample_descriptors(fmap, uv[None], 8)[0], expected)


def numpy_fps(xyz: np.ndarray, n: int, start: int = 0) -> np.ndarray:
    chosen, dist = [start], np.full(len(xyz), np.inf)
    for _ in range(n - 1):
        dist = np.minimum(dist, ((xyz - xyz[chosen[-1]]) ** 2).sum(1))
        chosen.append(int(np.argmax(dist)))
    return np.array(chosen)


FPS = pytest.mark.parametrize(
    "fps", [farthest_point_sampling, farthest_point_sampling_torch], ids=["compiled", "torch"]
)
BALLS = pytest.mark.parametrize("balls", [ball_query, ball_query_torch], ids=["compiled", "torch"])


@FPS
def test_fps_matches_brute_force(fps):
    xyz = np.random.default_rng(0).normal(size=(200, 3)).astype(np.float32)
    index = fps(torch.from_numpy(xyz)[None], 50, start=7)[0].numpy()
    np.testing.assert_array_equal(index, numpy_fps(xyz, 50, start=7))
    assert len(set(index.tolist())) == 50


@FPS
def test_batched_fps_equals_one_frame_at_a_time(fps):
    xyz = torch.from_numpy(np.random.default_rng(2).normal(size=(3, 400, 3)).astype(np.float32))
    batched = fps(xyz, 60)
    for b in range(3):
        assert torch.equal(batched[b], fps(xyz[b : b + 1], 60)[0])
        np.testing.assert_array_equal(batched[b].numpy(), numpy_fps(xyz[b].numpy(), 60))


@FPS
def test_fps_of_more_points_than_exist_takes_them_all_then_repeats_the_start(fps):
    index = fps(torch.rand(1, 5, 3), 9)[0].tolist()
    assert sorted(index[:5]) == [0, 1, 2, 3, 4] and index[5:] == [0, 0, 0, 0]


def brute_ball_query(xyz: np.ndarray, centres: np.ndarray, radius: float, nsample: int) -> np.ndarray:
    out = np.empty((len(centres), nsample), np.int64)
    for row, c in enumerate(centres):
        inside = np.flatnonzero(np.linalg.norm(xyz - c, axis=1) <= radius)[:nsample]
        out[row] = np.r_[inside, np.full(nsample - len(inside), inside[0])]
    return out


@BALLS
@pytest.mark.parametrize("nsample", [4, 16])
def test_ball_query_matches_brute_force(nsample, balls):
    xyz = np.random.default_rng(1).uniform(-1, 1, (300, 3)).astype(np.float32)
    centres = xyz[::7]
    chunk = {"chunk": 8} if balls is ball_query_torch else {}
    index = balls(torch.from_numpy(xyz)[None], torch.from_numpy(centres)[None], 0.35, nsample, **chunk)[0]
    np.testing.assert_array_equal(index.numpy(), brute_ball_query(xyz, centres, 0.35, nsample))


@BALLS
def test_ball_query_pads_when_the_cloud_is_smaller_than_nsample(balls):
    xyz = torch.tensor([[0.0, 0, 0], [0.05, 0, 0], [5.0, 0, 0]])
    assert balls(xyz[None], xyz[None, :1], 0.1, 4).tolist() == [[[0, 1, 0, 0]]]


@pytest.mark.parametrize("nearest_of", [three_nn, three_nn_torch], ids=["compiled", "torch"])
def test_three_nn_interpolation_by_hand(nearest_of):
    known = torch.tensor([[0.0, 0, 0], [2.0, 0, 0], [0.0, 10, 0], [50.0, 0, 0]])
    feats = torch.tensor([[1.0], [3.0], [100.0], [-1e6]])  # the 4th is never among the 3 nearest
    # distances 0.5, 1.5, sqrt(100.25); weights 1/d normalised
    w = np.array([1 / 0.5, 1 / 1.5, 1 / np.sqrt(100.25)])
    expected = (w * [1.0, 3.0, 100.0]).sum() / w.sum()
    queries = torch.tensor([[[0.5, 0, 0], [2.0, 0, 0]]])
    nearest = nearest_of(queries, known[None])
    assert sorted(nearest[0, 0].tolist()) == [0, 1, 2]
    out = interpolate(queries, known[None], feats[None], nearest)[0]
    assert out[0, 0].item() == pytest.approx(expected, rel=1e-5)
    assert out[1, 0].item() == pytest.approx(3.0, rel=1e-5)  # a query on a known point takes its feature


def test_normalisations():
    cloud = torch.tensor([[1.0, 1, 1], [3.0, 1, 1], [2.0, 1, 1]])
    torch.testing.assert_close(normalize_points(cloud, cloud), torch.tensor([[-1.0, 0, 0], [1.0, 0, 0], [0.0, 0, 0]]))
    uv = torch.tensor([[0.0, 0.0], [100.0, 25.0], [200.0, 50.0]])
    expected = torch.tensor([[-1.0, -0.25], [0.0, 0.0], [1.0, 0.25]])
    torch.testing.assert_close(centred_pixels(uv, (200, 50), 0.5), expected)
    torch.testing.assert_close(centred_pixels(uv, (200, 50), 0.7), expected * 0.5 / 0.7)  # SuperGlue's span


def test_canonical_frame_by_hand():
    # planar offsets from the centroid (0, 2) lie on the y axis at -2, -1, 3: the major axis is y, and the third moment
    # along +y is -8 - 1 + 27 > 0, so canonical x = +y and canonical y = z cross x = -x; z is kept
    cloud = torch.tensor([[0.0, 0, 1], [0.0, 1, 1], [0.0, 5, 1]])
    expected = torch.tensor([[-2.0, 0, 0], [-1.0, 0, 0], [3.0, 0, 0]]) / 3
    torch.testing.assert_close(normalize_points(cloud, cloud, canonical=True), expected)
    flipped = cloud * torch.tensor([1.0, -1.0, 1.0])  # mirrored along y: the moment picks -y, same coordinates
    torch.testing.assert_close(normalize_points(flipped, flipped, canonical=True), expected)


def skewed_cloud(n: int = 4000) -> torch.Tensor:
    g = torch.Generator().manual_seed(0)
    cloud = torch.randn(n, 3, generator=g) * torch.tensor([20.0, 5.0, 1.0])
    cloud[:, 0] += 0.02 * cloud[:, 0] ** 2  # a longer tail on one side: the third moment has a clear sign
    return cloud


def moved(cloud: torch.Tensor, yaw: float, tx: float, ty: float) -> torch.Tensor:
    T = torch.from_numpy(make_transform(rot_z(yaw), np.array([tx, ty, 0.0]))).float()
    return cloud @ T[:3, :3].t() + T[:3, 3]


@pytest.mark.parametrize(("yaw", "tx", "ty"), [(0.3, 4.0, -7.0), (2.0, -10.0, 3.0), (-2.9, 0.0, 9.0), (5.5, 1, 1)])
def test_canonical_frame_ignores_the_protocols_yaw_and_planar_translation(yaw, tx, ty):
    cloud = skewed_cloud()
    other = moved(cloud, yaw, tx, ty)
    canonical = normalize_points(other, other, canonical=True)
    torch.testing.assert_close(canonical, normalize_points(cloud, cloud, canonical=True), atol=1e-5, rtol=0)
    assert not torch.allclose(normalize_points(other, other), normalize_points(cloud, cloud), atol=1e-2)


def test_a_half_size_image_samples_like_stride_16():
    # image_scale 0.5 maps u' = (u + 0.5) / 2 - 0.5, then stride 8: cell j is centred on pixel 16j + 7.5
    fmap = coordinate_map(3, 4)
    uv = torch.tensor([[7.5, 7.5], [16 * 3 + 7.5, 16 * 2 + 7.5], [20.0, 30.0]])
    expected = torch.tensor([[0.0, 0.0], [3.0, 2.0], [(20 - 7.5) / 16, (30 - 7.5) / 16]])
    torch.testing.assert_close(sample_descriptors(fmap, uv[None], 16)[0], expected)
    u_resized = (uv[:, :1] + 0.5) * 0.5 - 0.5
    torch.testing.assert_close(sample_descriptors(fmap, uv[None], 16)[0, :, 0], (u_resized[:, 0] - 3.5) / 8)


def test_official_three_nn_is_the_first_three_of_a_stable_sort():
    """the official FP's 3-NN (4 candidates ordered, a tied row sorted whole) on a grid where many distances tie:
    the same distances and indices as the first 3 of the stable sort of each row (lower index first at a tie)."""
    from i2pbench_edgeregnet.official.pointnet2 import square_distance
    from i2pbench_edgeregnet.official.pointnet2 import three_nn as official_three_nn

    g = torch.Generator().manual_seed(0)
    known = torch.randint(0, 4, (2, 300, 3), generator=g).float() / 4  # 64 sites, each repeated: ties everywhere
    xyz = torch.randint(0, 8, (2, 200, 3), generator=g).float() / 8
    dist, index = official_three_nn(xyz, known)
    full = square_distance(xyz, known).sort(dim=-1, stable=True)
    assert torch.equal(dist, full.values[..., :3]) and torch.equal(index, full.indices[..., :3])
    assert (full.values[..., 2] == full.values[..., 3]).any()  # the whole-row fallback was needed
    assert official_three_nn(xyz[:, :5], known[:, :2])[1].shape == (2, 5, 2)  # fewer than 3 known points
