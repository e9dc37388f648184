"""Cosine and oracle matchers on hand-made descriptors and a hand-placed scene."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from i2pbench_classic.matchers import CosineMatcher, OracleMatcher

from i2pbench.errors import StageError
from i2pbench.stages.components import TrainableMatcher
from i2pbench.types import Features, Frame, Keypoints2D, Keypoints3D

K = np.array([[700.0, 0.0, 600.0], [0.0, 700.0, 180.0], [0.0, 0.0, 1.0]])


def scene(T_gt: np.ndarray | None = None) -> tuple[Frame, Keypoints2D, Keypoints3D]:
    """Camera = LiDAR frame. 3D: (0,0,10) -> (600,180); (1,0,10) -> (670,180); (0,1,10) -> (600,250); one behind.

    2D: (601,180) 1 px from the first projection, (670,184) 4 px from the second, (900,300) far from everything.
    """
    xyz = np.array([[0, 0, 10], [1, 0, 10], [0, 1, 10], [0, 0, -10]], np.float32)
    points = np.concatenate([xyz, np.zeros((4, 1), np.float32)], axis=1)
    frame = Frame(
        "toy",
        "f",
        np.zeros((375, 1242, 3), np.uint8),
        points,
        np.zeros(4, np.int16),
        np.linalg.norm(xyz, axis=1),
        K,
        np.eye(4) if T_gt is None else T_gt,
    )
    kp2d = Keypoints2D(np.array([[601, 180], [670, 184], [900, 300]], np.float32))
    return frame, kp2d, Keypoints3D.from_index(frame, np.arange(4))


def features(d2, d3) -> Features:
    return Features(torch.tensor(d2, dtype=torch.float32), torch.tensor(d3, dtype=torch.float32))


# cos(2D_i, 3D_j):  2D0=(1,0): [0, .99944, -1];  2D1=(0,1): [1, .0333, 0];  2D2=(1,1)/sqrt2: [.7071, .7303, -.7071]
# best 3D per 2D: 1, 0, 1; best 2D per 3D: 1, 0, 1 -> mutual pairs (0,1) and (1,0); 2D2 loses 3D1 to 2D0.
HAND = features([[1, 0], [0, 1], [1, 1]], [[0, 2], [3, 0.1], [-1, 0]])


def test_cosine_mutual_nearest_neighbours():
    frame, _, _ = scene()
    m = CosineMatcher()(frame, None, None, HAND)
    assert m.index2d.tolist() == [0, 1] and m.index3d.tolist() == [1, 0]
    np.testing.assert_allclose(m.score, [3 / math.sqrt(9.01), 1.0], rtol=1e-6)


def test_cosine_min_similarity_drops_weak_pairs():
    frame, _, _ = scene()
    m = CosineMatcher({"min_similarity": 0.9995})(frame, None, None, HAND)
    assert m.index2d.tolist() == [1] and m.index3d.tolist() == [0]


def test_cosine_with_no_keypoints_on_one_side():
    frame, _, _ = scene()
    m = CosineMatcher()(frame, None, None, Features(torch.zeros(0, 2), torch.ones(3, 2)))
    assert len(m) == 0


def test_cosine_without_descriptors_is_a_stage_error():
    frame, _, _ = scene()
    with pytest.raises(StageError, match="descriptors"):
        CosineMatcher()(frame, None, None, Features(None, torch.ones(3, 2)))


def test_cosine_is_a_trainable_matcher_and_oracle_is_not():
    assert isinstance(CosineMatcher(), TrainableMatcher)
    assert not isinstance(OracleMatcher(), TrainableMatcher)


def test_dual_softmax_loss_hand_value():
    # GT pairs: 3D0 <-> 2D0 (1 px), and with eps_c = 5 also 3D1 <-> 2D1 (4 px). Descriptors: 2D_i = 3D_i = e_i.
    # sim = I (3x4 block), logits = sim / 0.1. For pair (0,0): row log-softmax = 10 - log(e^10 + 3),
    # column log-softmax = 10 - log(e^10 + 2); same for (1,1). NLL = mean of -(sum of both).
    frame, kp2d, kp3d = scene()
    eye = np.eye(4)
    feats = features(eye[:3], eye)
    loss, terms = CosineMatcher({"radius_px": 5.0}).loss(frame, kp2d, kp3d, feats)
    expected = -(10 - math.log(math.exp(10) + 3)) - (10 - math.log(math.exp(10) + 2))
    assert terms["gt_pairs"] == 2
    assert float(loss) == pytest.approx(expected, rel=1e-2)  # ~2.3e-4, computed in float32


def test_loss_trains_descriptors():
    frame, kp2d, kp3d = scene()
    d2 = torch.randn(3, 8, generator=torch.Generator().manual_seed(0), requires_grad=True)
    d3 = torch.randn(4, 8, generator=torch.Generator().manual_seed(1), requires_grad=True)
    matcher, opt = CosineMatcher({"radius_px": 5.0}), torch.optim.SGD([d2, d3], lr=1.0)
    first = None
    for _ in range(50):
        loss, _ = matcher.loss(frame, kp2d, kp3d, Features(d2, d3))
        first = float(loss.detach()) if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss.detach()) < 0.2 * first
    assert CosineMatcher()(frame, kp2d, kp3d, Features(d2.detach(), d3.detach())).index3d.tolist()[:2] == [0, 1]


def test_loss_without_ground_truth_pairs_is_zero_and_differentiable():
    frame, kp2d, kp3d = scene()
    d2 = torch.ones(3, 4, requires_grad=True)
    loss, terms = CosineMatcher({"radius_px": 0.5}).loss(frame, kp2d, kp3d, Features(d2, torch.ones(4, 4)))
    loss.backward()
    assert float(loss.detach()) == 0.0 and terms["gt_pairs"] == 0


def test_oracle_pairs_within_eps_c_and_scores_by_distance():
    frame, kp2d, kp3d = scene()
    m = OracleMatcher()(frame, kp2d, kp3d, Features(None, None))  # default eps_c = frame's 3 px
    assert m.index3d.tolist() == [0] and m.index2d.tolist() == [0]
    np.testing.assert_allclose(m.score, [-1.0])
    m = OracleMatcher({"radius_px": 5.0})(frame, kp2d, kp3d, Features(None, None))
    assert m.index3d.tolist() == [0, 1] and m.index2d.tolist() == [0, 1]
    np.testing.assert_allclose(m.score, [-1.0, -4.0])


def test_oracle_follows_the_ground_truth_pose():
    T = np.eye(4)
    T[0, 3] = 1.0 / 7.0  # shifts every projection at depth 10 by +10 px in u: 3D0 -> (610, 180), 9 px from 2D0
    frame, kp2d, kp3d = scene(T)
    assert len(OracleMatcher()(frame, kp2d, kp3d, Features(None, None))) == 0
    m = OracleMatcher({"radius_px": 9.5})(frame, kp2d, kp3d, Features(None, None))
    assert m.index3d.tolist() == [0] and m.score[0] == pytest.approx(-9.0, abs=1e-5)


def test_oracle_without_ground_truth_is_a_stage_error():
    frame, kp2d, kp3d = scene()
    with pytest.raises(StageError, match="ground-truth"):
        OracleMatcher()(frame.without_ground_truth(), kp2d, kp3d, Features(None, None))
