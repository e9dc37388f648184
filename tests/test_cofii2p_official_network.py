"""CoFiI2P's official network outside the reference sets: its 'test' mode's coarse selection, nearest points and
patches on small cases worked out by hand (tests/test_cofii2p_reference.py proves the whole function on the
authors' tensors)."""

import pytest
import torch
from i2pbench_cofii2p.official.network import extract_patches, nearest_point, pairs_above, select_pairs

H, W = 20, 64  # KITTI's stride-8 map, the one the authors' border (x in [2, 62], y in [2, 18]) was written for


def image_descriptors(marks: dict[tuple[int, int], tuple[float, float]]) -> torch.Tensor:
    """[1 x 2 x H x W]: every pixel (-1, 0), the marked (x, y) pixels their own unit descriptors."""
    desc = torch.zeros(1, 2, H, W)
    desc[0, 0] = -1
    for (x, y), value in marks.items():
        desc[0, :, y, x] = torch.tensor(value)
    return desc


IMAGE = image_descriptors({(5, 3): (1.0, 0.0), (0, 0): (0.0, 1.0), (10, 4): (0.6, 0.8)})
POINTS = torch.tensor([[1.0, 1.0, 0.0, 0.6, 0.6], [0.0, 0.0, 1.0, 0.8, 0.8]])  # [C x N]: super-point descriptors


def test_pairs_above_keeps_scored_points_whose_best_pixel_is_inside_the_border():
    score = torch.tensor([[[0.95, 0.5, 0.92, 0.91, 0.3]]])
    xy, chosen = pairs_above(score, POINTS, IMAGE, 0.9)
    assert chosen.tolist() == [0, 3]  # point 2's best pixel (0, 0) lies outside the border
    assert xy.tolist() == [[5.0, 10.0], [3.0, 4.0]]


def test_select_pairs_lowers_the_threshold_by_steps_until_four_pairs():
    score = torch.tensor([[[0.95, 0.5, 0.92, 0.91, 0.3]]])
    trace: dict = {}
    xy, chosen = select_pairs(score, POINTS, IMAGE, trace)
    assert chosen.tolist() == [0, 1, 3, 4]  # 2 pairs at 0.9, 3 from 0.5, 4 from 0.3
    assert float(trace["score_threshold"]) == pytest.approx(0.3, abs=1e-6)  # 30 steps of 0.02 from 0.9
    assert xy.tolist() == [[5.0, 5.0, 10.0, 10.0], [3.0, 3.0, 4.0, 4.0]]


def test_select_pairs_refuses_where_the_authors_loop_would_never_end():
    outside = image_descriptors({(0, 0): (1.0, 0.0)})
    with pytest.raises(ValueError, match="fewer than 4 super-points match a super-pixel inside x"):
        select_pairs(torch.ones(1, 1, 5), POINTS, outside)


def test_nearest_point_and_patches():
    cloud = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [5.0, 5.0, 5.0]])
    assert nearest_point(cloud, torch.tensor([[0.9, 0.1, 0.0], [0.1, 0.0, 0.2]])).tolist() == [1, 0]
    fmap = torch.arange(36.0).reshape(1, 1, 6, 6)  # value = 6 y + x
    patch = extract_patches(fmap, torch.tensor([[3.0], [2.0]]))  # centre x 3, y 2: columns 1-4, rows 0-3
    assert patch.shape == (1, 1, 4, 4)
    assert patch[0, 0].tolist() == [[6 * y + x for x in range(1, 5)] for y in range(4)]
    with pytest.raises(ValueError, match=r"patch at centre \[1.0, 1.0\] reaches outside the 6 x 6 map"):
        extract_patches(fmap, torch.tensor([[3.0, 1.0], [2.0, 1.0]]))
