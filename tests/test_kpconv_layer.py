"""The shared KPConv layer (i2pbench.layers.kpconv) against values worked out by hand: the linear kernel influence,
GeoTransformer's normalisation by the neighbours whose features sum above zero, the shadow row of short lists; and
the seeded kernel disposition's shape."""

import numpy as np
import pytest
import torch

from i2pbench.layers.kpconv import KPConv, gather_rows, kernel_disposition, nearest_upsample, neighbour_maxpool

SUPPORT = torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
QUERY = torch.zeros(1, 3)
LISTS = torch.tensor([[0, 1, 2]])  # both points and the shadow row (index 2 = number of support points)


@pytest.fixture
def conv() -> KPConv:
    layer = KPConv(2, 1, kernel_size=2, radius=0.1, sigma=0.2)
    with torch.no_grad():
        layer.kernel_points.copy_(torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]))
        layer.weights.copy_(torch.tensor([[[1.0], [1.0]], [[1.0], [0.0]]]))
        layer.bias.fill_(0.25)
    return layer


@pytest.mark.parametrize(("second", "expected"), [
    # influences (1 - d / 0.2): point 0 -> kernels (1, 0.5), point 1 -> (0.5, 1), the shadow none.
    # kernel 0 sees f0 + 0.5 f1, kernel 1 sees 0.5 f0 + f1; weights sum kernel 0's channels, take kernel 1's first.
    ([3.0, 5.0], ((1 + 1.5) + (2 + 2.5) + (0.5 + 3)) / 2 + 0.25),  # both neighbours' features sum above 0: / 2
    ([3.0, -5.0], ((1 + 1.5) + (2 - 2.5) + (0.5 + 3)) / 1 + 0.25),  # the second sums to -2: not counted, / 1
])  # fmt: skip
def test_kpconv_weighs_by_linear_influence_and_counts_positive_neighbours(conv, second, expected):
    feats = torch.tensor([[1.0, 2.0], second])
    out = conv(feats, QUERY, SUPPORT, LISTS)
    assert out.shape == (1, 1)
    assert out.item() == pytest.approx(expected, abs=1e-6)


def test_shadow_row_pads_lists_with_zeros():
    feats = torch.tensor([[1.0, -2.0], [3.0, -5.0]])
    assert neighbour_maxpool(feats, LISTS).tolist() == [[3.0, 0.0]]  # the shadow's zero beats the negatives
    assert nearest_upsample(feats, torch.tensor([[1, 0], [2, 0]])).tolist() == [[3.0, -5.0], [0.0, 0.0]]
    assert gather_rows(SUPPORT, torch.tensor([2]), fill=7.0).tolist() == [[7.0, 7.0, 7.0]]


def test_kernel_disposition_is_seeded_centred_and_spread():
    points = kernel_disposition(15, 2.0, seed=3)
    assert points.shape == (15, 3) and points.dtype == np.float32
    np.testing.assert_array_equal(points, kernel_disposition(15, 2.0, seed=3))
    assert not np.array_equal(points, kernel_disposition(15, 2.0, seed=4))
    radii = np.linalg.norm(points, axis=1)
    assert radii[0] < 0.1  # the fixed centre point, jittered by 1 % of the radius
    assert radii[1:].mean() == pytest.approx(0.66 * 2.0, rel=0.03)  # KPConv's ratio of the radius
    gaps = np.linalg.norm(points[:, None] - points[None], axis=-1) + np.eye(15) * 99
    assert gaps.min() > 0.4 * 2.0  # repulsion spreads the 14 shell points (random ones come far closer)
