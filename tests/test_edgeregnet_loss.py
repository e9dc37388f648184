"""EdgeRegNet's assignment, match selection and loss on a 2 x 3 case worked out by hand."""

import math

import pytest
import torch
from i2pbench_edgeregnet.loss import edgeregnet_loss, log_assignment
from i2pbench_edgeregnet.matching import mutual_matches

# exp(S) = [[1, 2, 1], [1, 1, 2]]
#   softmax over 3D (rows):    [[1/4, 1/2, 1/4], [1/4, 1/4, 1/2]]
#   softmax over 2D (columns): [[1/2, 2/3, 1/3], [1/2, 1/3, 2/3]]
# sigma2D = [1/2, 3/4] (logits 0, ln 3); sigma3D = [1/2, 1/2, 1/4] (logits 0, 0, -ln 3)
SIM = torch.log(torch.tensor([[1.0, 2.0, 1.0], [1.0, 1.0, 2.0]]))
Z2D = torch.tensor([0.0, math.log(3)])
Z3D = torch.tensor([0.0, 0.0, -math.log(3)])
P = torch.tensor(
    [
        [1 / 2 * 1 / 2 * 1 / 2 * 1 / 4, 1 / 2 * 1 / 2 * 2 / 3 * 1 / 2, 1 / 2 * 1 / 4 * 1 / 3 * 1 / 4],
        [3 / 4 * 1 / 2 * 1 / 2 * 1 / 4, 3 / 4 * 1 / 2 * 1 / 3 * 1 / 4, 3 / 4 * 1 / 4 * 2 / 3 * 1 / 2],
    ]
)  # = [[1/32, 1/12, 1/96], [3/64, 1/32, 1/16]]


def one(*tensors):
    """a batch of one frame."""
    return [t[None] for t in tensors]


def test_log_assignment_is_eq_10():
    torch.testing.assert_close(log_assignment(*one(SIM, Z2D, Z3D))[0].exp(), P)


def test_padded_rows_and_columns_take_no_part_in_the_assignment():
    sim = torch.full((1, 3, 5), 7.0)  # padding of any value
    sim[0, :2, :3] = SIM
    z2d, z3d = torch.zeros(1, 3), torch.zeros(1, 5)
    z2d[0, :2], z3d[0, :3] = Z2D, Z3D
    masks = torch.tensor([[True, True, False]]), torch.tensor([[True, True, True, False, False]])
    torch.testing.assert_close(log_assignment(sim, z2d, z3d, *masks)[0, :2, :3].exp(), P)


def test_mutual_maxima_and_threshold():
    log_p = log_assignment(*one(SIM, Z2D, Z3D))[0]
    i2d, i3d, score = mutual_matches(log_p, 0.0)
    assert list(zip(i2d.tolist(), i3d.tolist(), strict=True)) == [(0, 1), (1, 2)]  # (1, 0) is a column max only
    torch.testing.assert_close(score, torch.tensor([1 / 12, 1 / 16]))
    i2d, i3d, _ = mutual_matches(log_p, 0.07)
    assert (i2d.tolist(), i3d.tolist()) == ([0], [1])


def two_argmaxes(log_p: torch.Tensor, threshold: float) -> tuple[list[int], list[int]]:
    """the mutual rule by its definition: torch's argmax (first maximum) along both dimensions."""
    best3d, best2d, rows = log_p.argmax(1), log_p.argmax(0), torch.arange(len(log_p))
    value = log_p[rows, best3d]
    keep = (best2d[best3d] == rows) & (value.exp() > threshold) & torch.isfinite(value)
    return rows[keep].tolist(), best3d[keep].tolist()


@pytest.mark.parametrize("seed", range(6))
def test_mutual_matches_are_the_two_argmaxes_even_with_ties_and_masked_rows_and_columns(seed):
    generator = torch.Generator().manual_seed(seed)
    log_p = torch.randint(-5, 0, (40, 30), generator=generator).float()  # few values: ties in most rows and columns
    log_p[:, 3], log_p[7], log_p[11, 5] = float("-inf"), float("-inf"), 0.0
    i2d, i3d, score = mutual_matches(log_p, 0.0)
    assert (i2d.tolist(), i3d.tolist()) == two_argmaxes(log_p, 0.0)
    assert (11, 5) in zip(i2d.tolist(), i3d.tolist(), strict=True) and len(i2d) >= 3
    torch.testing.assert_close(score, log_p[i2d, i3d].exp())
    assert (mutual_matches(log_p, 0.2)[0].tolist(), mutual_matches(log_p, 0.2)[1].tolist()) == two_argmaxes(log_p, 0.2)


def test_masked_points_never_match():
    log_p = log_assignment(*one(SIM, Z2D, Z3D))[0].masked_fill(torch.tensor([[False, True, True]]), float("-inf"))
    i2d, i3d, _ = mutual_matches(log_p, 0.0)
    assert (i2d.tolist(), i3d.tolist()) == ([1], [0])


def test_loss_by_hand():
    log_p, z2d, z3d = one(SIM, Z2D, Z3D)
    log_p = log_assignment(log_p, z2d, z3d)
    z_fov = torch.tensor([[math.log(4), 0.0, -math.log(4)]])  # fov scores 0.8, 0.5, 0.2
    pairs = (torch.tensor([[0, 1]]), torch.tensor([[1, 2]]), torch.tensor([[True, True]]))
    matchable = (torch.tensor([[True, True]]), torch.tensor([[False, True, True]]))
    in_fov = torch.tensor([[True, True, False]])
    masks = (torch.ones(1, 2, dtype=torch.bool), torch.ones(1, 3, dtype=torch.bool))
    total, terms = edgeregnet_loss(log_p, z2d, z3d, z_fov, pairs, matchable, in_fov, masks, weights=(1.0, 2.0, 0.5))

    l_fov = -(math.log(0.8) + math.log(0.5) + math.log(0.8)) / 3  # = 0.3797
    l_sigma = -(math.log(1 / 2) + math.log(3 / 4)) / 2 - (math.log(1 / 2) + math.log(1 / 2) + math.log(1 / 4)) / 3
    l_p = -(math.log(1 / 12) + math.log(1 / 16)) / 2  # = ln(192) / 2 = 2.6289
    assert terms == pytest.approx({"fov": l_fov, "sigma": l_sigma, "P": l_p, "pairs": 2.0}, rel=1e-5)
    assert terms["sigma"] == pytest.approx(0.4904 + 0.9242, abs=1e-4)
    assert total.item() == pytest.approx(l_fov + 2 * l_sigma + 0.5 * l_p, rel=1e-5)


def test_no_true_pair_gives_zero_p_term_and_still_trains_the_heads():
    sim, z2d, z3d = (t[None].clone().requires_grad_() for t in (SIM, Z2D, Z3D))
    z_fov = torch.zeros(1, 3, requires_grad=True)
    no_pairs = (
        torch.zeros(1, 0, dtype=torch.long),
        torch.zeros(1, 0, dtype=torch.long),
        torch.zeros(1, 0, dtype=torch.bool),
    )
    matchable = (torch.zeros(1, 2, dtype=torch.bool), torch.zeros(1, 3, dtype=torch.bool))
    masks = (torch.ones(1, 2, dtype=torch.bool), torch.ones(1, 3, dtype=torch.bool))
    in_fov = torch.ones(1, 3, dtype=torch.bool)
    total, terms = edgeregnet_loss(log_assignment(sim, z2d, z3d), z2d, z3d, z_fov, no_pairs, matchable, in_fov, masks)
    assert terms["P"] == 0.0 and terms["pairs"] == 0.0
    total.backward()
    assert z_fov.grad.abs().sum() > 0 and z2d.grad.abs().sum() > 0
    assert torch.isfinite(sim.grad).all()
