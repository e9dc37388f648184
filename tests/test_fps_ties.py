"""Farthest point sampling decides as the PointNet++ code of the official sizes does (issue 39): the squared distance
is `sum((xyz - centroid) ** 2, -1)` in float32 (each square rounded, summed x + y, then + z) and `torch.max` over
the running minimum takes the first index at an exact tie. Checked on clouds built to hold ties, against index
sequences computed by hand and against that rule written out in torch."""

import numpy as np
import pytest
import torch

from i2pbench.layers.pointnet2 import farthest_point_sampling, farthest_point_sampling_torch

PATHS = {"compiled": farthest_point_sampling, "torch": farthest_point_sampling_torch}

# integer points: every squared distance is exact, so the ties below are ties in any arithmetic
TIES = np.array(
    [[0, 0, 0], [0, 0, 1], [2, 0, 0], [0, 2, 0], [-2, 0, 0], [0, -2, 0], [1, 1, 0]], np.float32
)  # fmt: skip
# by hand. start 0: the four points at distance 4 (2, 3, 4, 5) tie -> 2; then 3, 4, 5 tie at 4 -> 3; then 4, 5
# -> 4; then 5; then 6 (min distance 2) before 1 (1). Start 6: 4 and 5 tie at 10 -> 4; 5 (8); 1 (3); 2 and 3 tie at
# 2 -> 2; 3; 0.
BY_HAND = {0: [0, 2, 3, 4, 5, 6, 1], 6: [6, 4, 5, 1, 2, 3, 0]}
# the same rule taking the LAST index at a tie would start 0, 5, 4, ...: the sequences above tell the rules apart
LAST_AT_TIE = {0: [0, 5, 4]}

# four points of a real KITTI scan (sequence 00, frame 0, normalised) where the rule's rounding decides: after 0
# and 3 are chosen, point 2's distance to 0 and point 1's to 3 are 5.0827246e-05 and 5.0827242e-05 with each square
# rounded (the authors' sum), but the same float32 value when the sum is fused (a*b + c rounded once): a fused FPS
# sees a tie there and takes 1, the authors' code takes 2 (two of 5,120 centroids swapped places on that scan)
ROUNDING = np.array(
    [
        [-1.4666927e-01, -1.6855378e-01, 1.8826507e-02],
        [7.519577e-02, -1.5073386e-01, 3.3390936e-03],
        [-1.4245568e-01, -1.6333698e-01, 1.6406206e-02],
        [8.0625765e-02, -1.47674e-01, -1.2206136e-04],
    ],
    np.float32,
)
ROUNDING_BY_HAND = [0, 3, 2, 1]


def authors_rule(xyz: torch.Tensor, n: int, start: int) -> list[int]:
    """the PointNet++ loop as the authors' code writes it (torch.sum of squares, strict update, torch.max)."""
    distance = torch.full(xyz.shape[:1], 1e10)
    farthest, out = start, []
    for _ in range(n):
        out.append(farthest)
        dist = torch.sum((xyz - xyz[farthest]) ** 2, -1)
        mask = dist < distance
        distance[mask] = dist[mask]
        farthest = int(torch.max(distance, -1)[1])
    return out


def squared(a: np.ndarray, b: np.ndarray) -> np.float32:
    """float32 squared distance with each square rounded, summed x + y, then + z (numpy does not fuse)."""
    d = (a - b).astype(np.float32)
    return (d[0] * d[0] + d[1] * d[1]) + d[2] * d[2]


@pytest.mark.parametrize("path", sorted(PATHS))
@pytest.mark.parametrize("start", sorted(BY_HAND))
def test_fps_takes_the_first_index_at_exact_ties(path, start):
    xyz = torch.from_numpy(TIES)
    got = PATHS[path](xyz[None], len(TIES), start)[0].tolist()
    assert got == BY_HAND[start] == authors_rule(xyz, len(TIES), start)
    if start in LAST_AT_TIE:
        assert got[:3] != LAST_AT_TIE[start]


def test_the_rounding_case_is_a_strict_maximum_in_the_authors_arithmetic():
    # the hand computation behind ROUNDING_BY_HAND: at step 2, point 2 is strictly the farther
    d2 = min(squared(ROUNDING[2], ROUNDING[0]), squared(ROUNDING[2], ROUNDING[3]))
    d1 = min(squared(ROUNDING[1], ROUNDING[0]), squared(ROUNDING[1], ROUNDING[3]))
    assert d2 > d1
    assert (d2 - d1) / d2 < 1e-6  # one float32 step apart: any other rounding of the sum can tie or swap them


@pytest.mark.parametrize("path", sorted(PATHS))
def test_fps_rounds_its_distances_as_the_authors_code(path):
    xyz = torch.from_numpy(ROUNDING)
    got = PATHS[path](xyz[None], 4, 0)[0].tolist()
    assert got == ROUNDING_BY_HAND == authors_rule(xyz, 4, 0)
