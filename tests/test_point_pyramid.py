"""CoFiI2P's point pyramid (i2pbench.layers.point_pyramid): hand-checked neighbours and halvings on tiny clouds, and
equality with the authors' preprocess_data.py on a real KITTI scan when I2PBENCH_COFII2P_CHECKOUT names a checkout
of WHU-USI3DV/CoFiI2P (their open3d.ml KNNSearch stood in for by their own pure-torch knn, as their file offers)."""

from __future__ import annotations

import importlib.util
import os
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import sample

from i2pbench.layers import point_pyramid as pyramid
from i2pbench.scoring.protocol_peer import draw_points, voxel_grid

POINTS = 8192


def test_knn_lists_each_querys_neighbours_nearest_first():
    database = torch.tensor([[0.0, 0, 0], [1, 0, 0], [3, 0, 0], [0, 2, 0]])
    queries = torch.tensor([[0.9, 0, 0], [0, 1.8, 0]])
    # query 0 at x = 0.9: distances 0.81, 0.01, 4.41, 4.81 -> rows 1, 0, 2; query 1 at y = 1.8: 3.24 (row 0),
    # 1 + 3.24 = 4.24 (row 1), 9 + 3.24 = 12.24 (row 2), 0.04 (row 3) -> rows 3, 0, 1
    np.testing.assert_array_equal(pyramid.knn(database, queries, 3), [[1, 0, 2], [3, 0, 1]])


def test_knn_takes_its_queries_in_blocks_with_the_same_answer(monkeypatch):
    points = torch.from_numpy(np.random.default_rng(0).uniform(-20, 20, (300, 3)).astype(np.float32))
    whole = pyramid.knn(points, points, 16)
    monkeypatch.setattr(pyramid, "QUERY_BLOCK", 7)
    assert torch.equal(pyramid.knn(points, points, 16), whole)
    assert torch.equal(whole[:, 0], torch.arange(300))  # every point is its own nearest


def test_each_level_is_a_random_half_of_the_one_above_drawn_with_repeats():
    picks = pyramid.halvings(16, 4, np.random.RandomState(3))
    assert [len(p) for p in picks] == [16, 8, 4, 2]
    # the draws are numpy's legacy choice over the level above: indices into it, mapped to rows of level 0
    state = np.random.RandomState(3)
    first = state.choice(np.arange(16), size=8)
    second = first[state.choice(np.arange(8), size=4)]
    np.testing.assert_array_equal(picks[1], first)
    np.testing.assert_array_equal(picks[2], second)
    assert len(np.unique(pyramid.halvings(4096, 2, np.random.RandomState(0))[1])) < 2048  # repeats: with replacement


def test_the_pyramid_links_its_levels_by_nearest_neighbours():
    points = np.random.default_rng(1).uniform(-5, 5, (64, 3)).astype(np.float32)
    built = pyramid.point_pyramid(points, np.random.RandomState(0), stages=3, k=4)
    assert built.lengths == [64, 32, 16]
    for level, picks in zip(built.points, built.picks, strict=True):
        np.testing.assert_array_equal(level.numpy(), points[picks])
    # subsampling: each point of level 1, its nearest in level 0 is itself (a point of level 0 it was drawn as)
    nearest = built.subsampling[0][:, 0]
    np.testing.assert_array_equal(built.points[0][nearest].numpy(), built.points[1].numpy())
    assert [tuple(t.shape) for t in built.upsampling] == [(64, 4), (32, 4)]
    inputs = built.as_inputs(torch.zeros(64, 4))
    assert sorted(inputs) == ["feats", "lengths", "neighbors", "points", "subsampling", "upsampling"]


def _authors_preprocess(checkout: Path) -> types.ModuleType:
    """their preprocess_data.py, with open3d.ml's KNNSearch stood in for by the file's own `knn`."""
    path = checkout / "model" / "kpconv" / "preprocess_data.py"
    if not path.is_file():
        pytest.fail(f"I2PBENCH_COFII2P_CHECKOUT={checkout}: no model/kpconv/preprocess_data.py there")
    holder: dict = {}

    class KNNSearch:
        def __init__(self, return_distances=False):
            pass

        def __call__(self, points, queries, k):
            return types.SimpleNamespace(neighbors_index=holder["knn"](points, queries, k).reshape(-1))

    layers = types.ModuleType("open3d.ml.torch.layers")
    layers.KNNSearch, layers.FixedRadiusSearch = KNNSearch, None
    stubs = {"open3d.ml": types.ModuleType("open3d.ml"), "open3d.ml.torch": types.ModuleType("open3d.ml.torch"),
             "open3d.ml.torch.layers": layers}  # fmt: skip
    saved = {name: sys.modules.get(name) for name in stubs}
    sys.modules.update(stubs)
    try:
        spec = importlib.util.spec_from_file_location("cofii2p_preprocess_data", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        for name, old in saved.items():
            sys.modules.pop(name) if old is None else sys.modules.__setitem__(name, old)
    holder["knn"] = module.knn
    return module


@pytest.fixture(scope="module")
def kitti_cloud() -> np.ndarray:
    """8,192 of a real KITTI scan's 0.1 m voxels, as the loader draws them -> [3 x 8192] float32 (their function at
    any size; at the loader's 20,480 the two agreed too, in 30 s instead of 5)."""
    scan = np.fromfile(sample("kitti_odometry", "sequences", "00", "velodyne", "000000.bin"), np.float32)
    voxels = voxel_grid(scan.reshape(-1, 4), 0.1)
    return np.ascontiguousarray(voxels[draw_points(len(voxels), POINTS, np.random.RandomState(7)), :3].T)


@pytest.fixture(scope="module")
def checkout() -> Path:
    path = os.environ.get("I2PBENCH_COFII2P_CHECKOUT", "")
    if not path:
        pytest.skip("I2PBENCH_COFII2P_CHECKOUT is not set: the path of a WHU-USI3DV/CoFiI2P checkout")
    return Path(path)


def test_reference_pyramid_equals_the_authors_preprocessing_on_a_kitti_scan(checkout, kitti_cloud):
    torch.set_num_threads(1)
    theirs_module = _authors_preprocess(checkout)
    np.random.seed(11)
    theirs = theirs_module.precompute_point_cloud_stack_mode(kitti_cloud, None, None, lengths=POINTS, num_stages=5)
    ours = pyramid.point_pyramid(kitti_cloud.T, np.random.RandomState(11)).as_inputs(torch.zeros(0))
    assert ours["lengths"] == theirs["lengths"] == [8192, 4096, 2048, 1024, 512]
    for key in ("points", "neighbors", "subsampling", "upsampling"):
        assert len(ours[key]) == len(theirs[key])
        for level, (mine, authors) in enumerate(zip(ours[key], theirs[key], strict=True)):
            assert torch.equal(mine, authors.to(mine.dtype)), (key, level)
