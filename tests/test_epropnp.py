"""i2pbench.layers.epropnp, EPro-PnP's Monte-Carlo pose loss: the Huber cost and its threshold by hand, the LM
solver recovering a pose, the gradient moving correspondence weights and points the right way, a true pose
scoring better than a perturbed one, and the estimate seeded. Against the authors' own copy of EPro-PnP
(VP2P-Match's utils/epropnp, from the checkout named by I2PBENCH_VP2P_CHECKOUT): the cost, the LM optimum and its
covariance, and with pyro installed the proposals' densities and refits."""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import pytest
import torch

from i2pbench.layers import epropnp as E

F64 = torch.float64
CHECKOUT = os.environ.get("I2PBENCH_VP2P_CHECKOUT")
K_CELLS = torch.tensor([[180.0, 0, 64], [0, 180, 20], [0, 0, 1]], dtype=F64)  # a quarter-size KITTI camera


def pose(t, q) -> torch.Tensor:
    return torch.cat([torch.tensor(t, dtype=F64), torch.nn.functional.normalize(torch.tensor(q, dtype=F64), dim=0)])


TRUE_POSE = pose([0.5, -0.2, 20.0], [3.0, 0.1, -0.2, 0.05])


def problem(
    noise: float = 0.0, outliers: int = 0, n: int = 40, moved: tuple[float, float] = (0.0, 0.0)
) -> tuple[E.Correspondences, torch.Tensor]:
    """points in front of the camera, their projections under TRUE_POSE (+ noise), the first moved by `moved`, the
    last `outliers` by 20 px; projections and weights (0.5) take gradients."""
    g = torch.Generator().manual_seed(0)
    x3d = torch.randn(1, n, 3, generator=g, dtype=F64) * torch.tensor([5.0, 2.0, 5.0], dtype=F64)
    exact = E.Correspondences(x3d, torch.zeros(1, n, 2, dtype=F64), torch.ones(1, n, 2, dtype=F64), K_CELLS[None],
                              torch.ones(1, dtype=F64))  # fmt: skip
    x2d = E.project(exact, TRUE_POSE[None]) + noise * torch.randn(1, n, 2, generator=g, dtype=F64)
    x2d[0, 0] += torch.tensor(moved, dtype=F64)
    if outliers:
        x2d[:, -outliers:] += 20.0
    x2d.requires_grad_(True)
    w2d = torch.full((1, n, 2), 0.5, dtype=F64, requires_grad=True)
    return E.Correspondences(x3d, x2d, w2d, K_CELLS[None], E.adaptive_delta(x2d, w2d, 0.1)), w2d


def test_huber_cost_and_its_adaptive_threshold_by_hand():
    x3d = torch.tensor([[[1.0, 2.0, 4.0], [0.0, 0.0, 2.0]]], dtype=F64)  # project (K = I) to (0.25, 0.5) and (0, 0)
    x2d = torch.tensor([[[0.25, 0.8], [3.0, 4.0]]], dtype=F64)
    w2d = torch.tensor([[[2.0, 2.0], [1.0, 1.0]]], dtype=F64)
    c = E.Correspondences(x3d, x2d, w2d, torch.eye(3, dtype=F64)[None], torch.ones(1, dtype=F64))
    identity = pose([0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])[None]
    # |w r| = 0.6 <= 1: 0.6^2 / 2 = 0.18; |w r| = 5 > 1: 1 x 5 - 1 / 2 = 4.5
    assert E.cost(c, identity).item() == pytest.approx(0.18 + 4.5, abs=1e-12)
    # spread sqrt(var(0.25, 3) + var(0.8, 4)) (unbiased), mean weight 1.5, relative 0.1
    spread = math.sqrt((3 - 0.25) ** 2 / 2 + (4 - 0.8) ** 2 / 2)
    assert E.adaptive_delta(x2d, w2d, 0.1).item() == pytest.approx(1.5 * spread * 0.1, abs=1e-12)


def test_the_tangent_step_turns_by_twice_its_length_on_the_camera_side():
    q = TRUE_POSE[3:]
    basis = E.tangent_basis(q)
    assert torch.allclose(basis.T @ basis, torch.eye(3, dtype=F64), atol=1e-12) and (q @ basis).abs().max() < 1e-12
    s = torch.tensor([0.0, 0.0, 1e-4], dtype=F64)  # about z, by 2e-4 rad
    moved = E.retract(TRUE_POSE, torch.cat([torch.zeros(3, dtype=F64), s]))
    turn = E.quaternion_matrix(moved[3:]) @ E.quaternion_matrix(q).T
    assert turn[1, 0].item() == pytest.approx(2e-4, rel=1e-6) and turn[0, 1].item() == pytest.approx(-2e-4, rel=1e-6)


def test_levenberg_marquardt_recovers_the_pose_of_exact_correspondences():
    c, _ = problem()
    start = E.retract(TRUE_POSE[None], torch.tensor([[0.5, 0.3, -1.0, 0.05, 0.02, -0.03]], dtype=F64))
    found, cov, cost = E.levenberg_marquardt(c, start, iterations=10)
    assert (found - TRUE_POSE).abs().max() < 1e-8 and cost.item() < 1e-12
    assert torch.allclose(cov, cov.transpose(1, 2)) and bool((torch.linalg.eigvalsh(cov) > 0).all())


def test_the_gradient_raises_inlier_weights_and_lowers_outlier_weights():
    c, w2d = problem(noise=0.3, outliers=8)
    E.monte_carlo_pose_loss(c, TRUE_POSE[None], torch.Generator().manual_seed(0))["loss"].sum().backward()
    inlier, outlier = w2d.grad[0, :-8], w2d.grad[0, -8:]
    assert inlier.mean() < 0 < outlier.min()  # descent makes the true pairs count more, the false ones less


def test_a_gradient_step_moves_a_perturbed_point_towards_its_true_projection():
    c, _ = problem(noise=0.3, moved=(4.0, -3.0))
    truth = E.project(c.detached(), TRUE_POSE[None])[0, 0]
    E.monte_carlo_pose_loss(c, TRUE_POSE[None], torch.Generator().manual_seed(0))["loss"].sum().backward()
    before = (c.x2d[0, 0] - truth).norm()
    after = (c.x2d[0, 0] - 0.5 * c.x2d.grad[0, 0] / c.x2d.grad[0, 0].norm() - truth).norm()
    assert after < before - 0.4  # a half-pixel step along the descent direction closes most of half a pixel


def test_the_true_pose_costs_less_than_a_perturbed_one():
    c, _ = problem(noise=0.3)
    perturbed = E.retract(TRUE_POSE[None], torch.tensor([[0.3, -0.2, 0.5, 0.01, -0.02, 0.0]], dtype=F64))
    true_loss = E.monte_carlo_pose_loss(c, TRUE_POSE[None], torch.Generator().manual_seed(0))["loss"]
    perturbed_loss = E.monte_carlo_pose_loss(c, perturbed, torch.Generator().manual_seed(0))["loss"]
    assert true_loss.item() < perturbed_loss.item()


def test_the_monte_carlo_estimate_is_seeded():
    c, _ = problem(noise=0.3)

    def loss(seed: int) -> torch.Tensor:
        return E.monte_carlo_pose_loss(c, TRUE_POSE[None], torch.Generator().manual_seed(seed))["loss"].detach()

    first, again, other = loss(7), loss(7), loss(8)
    assert torch.equal(first, again) and not torch.equal(first, other)
    assert abs(first.item() - other.item()) < 1.0  # two estimates of one integral, not two different losses


def test_samples_must_split_into_rounds():
    c, _ = problem()
    with pytest.raises(ValueError, match="do not split"):
        E.monte_carlo_pose_loss(c, TRUE_POSE[None], torch.Generator(), samples=10, rounds=4)


@pytest.fixture(scope="module")
def authors():
    """the authors' utils/epropnp modules, from the checkout (torch.cholesky, gone from newer torch, stood in for)."""
    if not CHECKOUT or not (Path(CHECKOUT) / "utils" / "epropnp").is_dir():
        pytest.skip("set I2PBENCH_VP2P_CHECKOUT to a junshengzhou/VP2P-Match checkout to compare with utils/epropnp")
    sys.path.insert(0, CHECKOUT)
    if not hasattr(torch, "cholesky"):
        torch.cholesky = lambda m, upper=False: torch.linalg.cholesky(m, upper=upper)
    from utils.epropnp import camera, cost_fun, levenberg_marquardt

    yield camera, cost_fun, levenberg_marquardt
    sys.path.remove(CHECKOUT)


def test_cost_and_lm_optimum_equal_the_authors_epropnp(authors):
    camera, cost_fun, lm = authors
    c, w2d = problem(noise=0.5, outliers=4)
    cam = camera.PerspectiveCamera(cam_mats=c.K, z_min=0.1)
    huber = cost_fun.AdaptiveHuberPnPCost(relative_delta=0.1)
    huber.set_param(c.x2d.detach(), w2d.detach())
    assert torch.allclose(huber.delta, c.delta, rtol=1e-12)
    start = E.retract(TRUE_POSE[None], torch.tensor([[0.5, 0.3, -1.0, 0.05, 0.02, -0.03]], dtype=F64))
    theirs = lm.LMSolver(dof=6, num_iter=10).solve(
        c.x3d, c.x2d.detach(), w2d.detach(), cam, huber, pose_init=start, with_pose_cov=True, with_cost=True
    )
    ours = E.levenberg_marquardt(c, start, iterations=10)
    assert (ours[0] - theirs[0]).abs().max() < 1e-9 and torch.allclose(ours[2], theirs[2], rtol=1e-9)
    # the covariance in each one's tangent basis: equal as the rotation precision in quaternion space
    T = camera.PerspectiveCamera.get_quaternion_transfrom_mat(theirs[0][:, 3:])
    precision = T @ torch.linalg.inv(theirs[1][:, 3:, 3:]) @ T.transpose(1, 2)
    basis = E.tangent_basis(ours[0][:, 3:])
    mine = basis @ torch.linalg.inv(ours[1][:, 3:, 3:]) @ basis.transpose(1, 2)
    assert (mine - precision).abs().max() <= 1e-6 * precision.abs().max()
    assert torch.allclose(ours[1][:, :3, :3], theirs[1][:, :3, :3], rtol=1e-9)


def test_proposals_equal_the_authors_distributions(authors):
    pytest.importorskip("pyro", reason="the authors' EPro-PnP proposals need pyro (pip install pyro-ppl)")
    from utils.epropnp import epropnp

    c, _ = problem(noise=0.5)
    found, cov, _ = E.levenberg_marquardt(c, TRUE_POSE[None], iterations=5)
    net = epropnp.EProPnP6DoF(mc_samples=64, num_iter=4)
    buffers = net.allocate_buffer(1, dtype=F64)
    cam = authors[0].PerspectiveCamera(cam_mats=c.K, z_min=0.1)
    net.initial_fit(found, cov, cam, *buffers)
    ours = E.first_proposal(found, cov, 0.001)
    samples = ours.sample(64, torch.Generator().manual_seed(1))
    trans, rot = net.gen_new_distr(0, *buffers)
    theirs = trans.log_prob(samples[..., :3]) + rot.log_prob(samples[..., 3:])
    assert torch.allclose(ours.log_prob(samples), theirs, rtol=1e-9, atol=1e-9)
    log_weights = torch.randn(64, 1, generator=torch.Generator().manual_seed(2), dtype=F64)
    net.estimate_params(0, samples, log_weights, *buffers)
    refit = E.refitted(samples, log_weights, 0.001)
    assert torch.allclose(refit.mode, buffers[0][1]) and torch.allclose(refit.t_tril, buffers[1][1])
    assert torch.allclose(refit.r_tril, buffers[2][1], rtol=1e-6, atol=1e-9)
