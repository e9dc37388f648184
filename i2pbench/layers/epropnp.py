"""EPro-PnP's Monte-Carlo pose loss for 6-DoF poses (Chen et al., CVPR 2022; tjiiv-cprg/EPro-PnP, Apache-2.0, whose
`ops/pnp` VP2P-Match ships as utils/epropnp), written anew in plain torch: no pyro, no compiled code, any device.

The weighted 2D-3D correspondences define a pose density p(y) proportional to exp(-cost(y)), cost the Huber-robust
reprojection error sum_i rho(||w_i * (pi(R x_i + t) - u_i)||). The loss is the KL divergence from a Dirac at the
true pose to that density, up to a constant: cost(y_gt) + log of the integral of exp(-cost), the integral estimated
by adaptive multiple importance sampling (AMIS) around the Levenberg-Marquardt optimum:
- proposals: translation a multivariate t (3 degrees of freedom), rotation an angular central Gaussian over unit
  quaternions, first fitted to the optimum's covariance (inverse Gauss-Newton Hessian), then refitted each round to
  the weighted samples drawn so far;
- each sample's log weight is -cost(sample) - log(the mixture of all proposals so far at it);
- the gradient reaches the correspondences through cost(y_gt) and cost(samples); the samples and proposals are
  constants, as upstream.

Poses are [..., 7]: translation (3) and a unit quaternion (w, x, y, z) rotating points into the camera. Give it
float64: on near-degenerate correspondences float32's solver and proposals turn 1e-7 input noise into estimates
several times apart (docs/methods.md, VP2P-Match's training). Kept
difference: upstream can start the solver from a random-sample LM (`RSLMSolver`) and keep whichever of that and the
true pose costs less; here the solver starts from the pose it is given (the true pose in training).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch.func import jacfwd, vmap

REVISION = 0

T_DOF = 3.0  # the translation proposal's degrees of freedom (upstream's MultivariateStudentT(3, ...))
EPS = 1e-5  # upstream's eps: LM damping floor, ACG estimation, radius floor


@dataclass(frozen=True)
class Correspondences:
    """x3d [B x N x 3], x2d [B x N x 2] pixels, w2d [B x N x 2] weights, K [B x 3 x 3], delta [B] the Huber
    threshold; z_min clamps depth before division (upstream's camera, 0.1)."""

    x3d: torch.Tensor
    x2d: torch.Tensor
    w2d: torch.Tensor
    K: torch.Tensor
    delta: torch.Tensor
    z_min: float = 0.1

    def detached(self) -> Correspondences:
        return Correspondences(*(t.detach() for t in (self.x3d, self.x2d, self.w2d, self.K, self.delta)), self.z_min)


def adaptive_delta(x2d: torch.Tensor, w2d: torch.Tensor, relative: float) -> torch.Tensor:
    """upstream's AdaptiveHuberPnPCost threshold [B]: mean weight x the 2D points' spread x `relative`."""
    return w2d.mean(dim=(-2, -1)) * x2d.var(dim=-2).sum(-1).sqrt() * relative


def quaternion_matrix(q: torch.Tensor) -> torch.Tensor:
    """unit quaternions [..., 4] (w, x, y, z) -> rotation matrices [..., 3, 3]."""
    w, x, y, z = q.unbind(-1)
    rows = (
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    )  # fmt: skip
    return torch.stack(rows, -1).unflatten(-1, (3, 3))


def tangent_basis(q: torch.Tensor) -> torch.Tensor:
    """[..., 4, 3]: columns (0, e_k) * q (quaternion product), orthonormal and orthogonal to q, so q + basis @ s
    rotates by about 2|s| about s, applied on the camera side."""
    w, x, y, z = q.unbind(-1)
    cols = (-x, w, -z, y, -y, z, w, -x, -z, -y, x, w)  # (0, e_x) q, (0, e_y) q, (0, e_z) q, one after another
    return torch.stack(cols, -1).unflatten(-1, (3, 4)).transpose(-1, -2)


def retract(pose: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
    """pose [..., 7] moved by a tangent step [..., 6] (translation, rotation)."""
    q = pose[..., 3:]
    turned = q + (tangent_basis(q) @ step[..., 3:, None])[..., 0]
    return torch.cat([pose[..., :3] + step[..., :3], F.normalize(turned, dim=-1)], -1)


def project(c: Correspondences, pose: torch.Tensor) -> torch.Tensor:
    """x3d under pose [..., B, 7] through K -> pixels [..., B, N, 2] (depth clamped at z_min)."""
    cam = c.x3d @ quaternion_matrix(pose[..., 3:]).transpose(-1, -2) + pose[..., None, :3]
    h = cam @ c.K.transpose(-1, -2)
    return h[..., :2] / h[..., 2:].clamp(min=c.z_min)


def weighted_residuals(c: Correspondences, pose: torch.Tensor) -> torch.Tensor:
    """w2d * (projection - x2d) [..., B, N, 2]."""
    return (project(c, pose) - c.x2d) * c.w2d


def cost(c: Correspondences, pose: torch.Tensor) -> torch.Tensor:
    """the Huber cost [..., B]: per point rho(s) = s^2 / 2 below delta, delta s - delta^2 / 2 above."""
    s = weighted_residuals(c, pose).norm(dim=-1)
    delta = c.delta[..., None]
    return torch.where(s <= delta, 0.5 * s.square(), delta * s - 0.5 * delta.square()).sum(-1)


def robust_system(c: Correspondences, pose: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """the IRLS-rescaled residuals [B x 2N] and their Jacobian [B x 2N x 6] in the tangent step (the rescaling
    sqrt(min(1, delta / s)) held constant, as upstream's)."""

    def one(step, x3d, x2d, w2d, K, p):
        single = Correspondences(x3d[None], x2d[None], w2d[None], K[None], c.delta[:1], c.z_min)
        return weighted_residuals(single, retract(p, step)[None])[0].flatten()

    zero = pose.new_zeros(pose.shape[0], 6)
    args = (zero, c.x3d, c.x2d, c.w2d, c.K, pose)
    residual = vmap(one)(*args)
    jac = vmap(jacfwd(one))(*args)
    s = residual.unflatten(-1, (-1, 2)).norm(dim=-1)
    scale = (c.delta[:, None] / s.clamp(min=1e-10)).clamp(max=1.0).sqrt().repeat_interleave(2, -1)
    return residual * scale, jac * scale[..., None]


@torch.no_grad()
def levenberg_marquardt(c: Correspondences, pose: torch.Tensor, iterations: int = 5) -> tuple[torch.Tensor, ...]:
    """upstream's trust-region LM from `pose` [B x 7] -> (optimum [B x 7], tangent covariance [B x 6 x 6], cost [B])."""
    c = c.detached()
    pose = pose.clone()
    radius = pose.new_full((len(pose),), 30.0)
    decrease = pose.new_full((len(pose),), 2.0)
    eye = torch.eye(6, dtype=pose.dtype, device=pose.device)
    for _ in range(iterations):
        residual, jac = robust_system(c, pose)
        jtj, grad = jac.transpose(1, 2) @ jac, jac.transpose(1, 2) @ residual[..., None]
        damping = jtj.diagonal(dim1=1, dim2=2).clamp(1e-6, 1e32) / radius[:, None] + EPS
        step = -torch.linalg.solve(jtj + torch.diag_embed(damping), grad)
        moved = retract(pose, step[..., 0])
        predicted = -(step.transpose(1, 2) @ (jtj @ step / 2 + grad)).flatten()
        ratio = (cost(c, pose) - cost(c, moved)) / predicted
        ok = (ratio >= 1e-3) & (predicted > 0)
        pose = torch.where(ok[:, None], moved, pose)
        grown = radius / (1 - (2 * ratio - 1) ** 3).clamp(min=1 / 3)
        radius = torch.where(ok, grown, radius).clamp(EPS, 1e16)
        radius = torch.where(ok, radius, radius / decrease)
        decrease = torch.where(ok, torch.full_like(decrease, 2.0), decrease * 2)
    _, jac = robust_system(c, pose)
    return pose, torch.linalg.inv(jac.transpose(1, 2) @ jac + EPS * eye), cost(c, pose)


def cholesky_or_identity(cov: torch.Tensor) -> torch.Tensor:
    """lower Cholesky factors [B x d x d]; the identity where a matrix is not positive definite (upstream's
    fallback)."""
    tril, info = torch.linalg.cholesky_ex(cov)
    eye = torch.eye(cov.shape[-1], dtype=cov.dtype, device=cov.device).expand_as(cov)
    return torch.where((info == 0)[:, None, None], tril, eye)


def dispersed(rot_cov: torch.Tensor, dispersion: float) -> torch.Tensor:
    """upstream's ACG factor: chol(cov + det(cov)^(1/4) x dispersion x I)."""
    eye = torch.eye(4, dtype=rot_cov.dtype, device=rot_cov.device)
    return cholesky_or_identity(rot_cov + rot_cov.det().clamp(min=0)[:, None, None] ** 0.25 * dispersion * eye)


@dataclass(frozen=True)
class Proposal:
    """one AMIS round's proposal: translation t(3) [B x 3] with scale_tril [B x 3 x 3], rotation ACG scale_tril
    [B x 4 x 4]."""

    mode: torch.Tensor
    t_tril: torch.Tensor
    r_tril: torch.Tensor

    def sample(self, count: int, generator: torch.Generator) -> torch.Tensor:
        """[count x B x 7] poses."""
        b, like = len(self.mode), self.mode
        normal = torch.randn((count, b, 10), generator=generator, device=generator.device, dtype=like.dtype)
        normal = normal.to(like.device)
        chi2 = normal[..., 7:].square().sum(-1, keepdim=True)  # 3 degrees of freedom: three squared normals
        t = self.mode + (self.t_tril @ normal[..., :3, None])[..., 0] * torch.sqrt(T_DOF / chi2)
        q = F.normalize((self.r_tril @ normal[..., 3:7, None])[..., 0], dim=-1)
        return torch.cat([t, q], -1)

    def log_prob(self, pose: torch.Tensor) -> torch.Tensor:
        """log density [... x B] of poses [... x B x 7] (a quaternion's density on the 3-sphere)."""
        dev = torch.linalg.solve_triangular(self.t_tril, (pose[..., :3] - self.mode)[..., None], upper=False)
        maha = dev[..., 0].square().sum(-1)
        t = (
            math.lgamma((T_DOF + 3) / 2) - math.lgamma(T_DOF / 2) - 1.5 * math.log(T_DOF * math.pi)
            - self.t_tril.diagonal(dim1=-2, dim2=-1).log().sum(-1) - (T_DOF + 3) / 2 * torch.log1p(maha / T_DOF)
        )  # fmt: skip
        rot = torch.linalg.solve_triangular(self.r_tril, pose[..., 3:, None], upper=False)[..., 0]
        r = -2 * rot.square().sum(-1).log() - self.r_tril.diagonal(dim1=-2, dim2=-1).log().sum(-1)
        return t + r - math.log(2 * math.pi**2)


def first_proposal(pose: torch.Tensor, cov: torch.Tensor, dispersion: float) -> Proposal:
    """the proposal fitted to the LM optimum [B x 7] and its tangent covariance [B x 6 x 6] (upstream's
    `initial_fit`: the ACG's covariance (B H B^T + I)^-1, H the rotation block's precision, trace 1)."""
    basis = tangent_basis(pose[:, 3:])
    eye = torch.eye(4, dtype=pose.dtype, device=pose.device)
    rot_cov = torch.linalg.inv(basis @ torch.linalg.inv(cov[:, 3:, 3:]) @ basis.transpose(1, 2) + eye)
    rot_cov = rot_cov / rot_cov.diagonal(dim1=1, dim2=2).sum(-1)[:, None, None]
    return Proposal(pose[:, :3], cholesky_or_identity(cov[:, :3, :3]), dispersed(rot_cov, dispersion))


def refitted(samples: torch.Tensor, log_weights: torch.Tensor, dispersion: float, mle_rounds: int = 3) -> Proposal:
    """the next proposal from samples [S x B x 7] and their log weights [S x B] (upstream's `estimate_params`):
    weighted mean and covariance of translations, the ACG's maximum-likelihood fixed point for rotations."""
    w = log_weights.softmax(0)
    mode = (w[..., None] * samples[..., :3]).sum(0)
    dev = samples[..., :3] - mode
    t_cov = (w[..., None, None] * dev[..., :, None] * dev[..., None, :]).sum(0)
    q = samples[..., 3:]
    eye = torch.eye(4, dtype=q.dtype, device=q.device)
    rot_cov = eye.expand(q.shape[1], 4, 4)
    for _ in range(mle_rounds):
        m = (q[..., None, :] @ torch.linalg.inv(rot_cov) @ q[..., :, None])[..., 0, 0]
        inv_m = w / m.clamp(min=EPS)
        inv_m = inv_m / inv_m.sum(0)
        rot_cov = (inv_m[..., None, None] * q[..., :, None] * q[..., None, :]).sum(0) + EPS * eye
    return Proposal(mode, cholesky_or_identity(t_cov), dispersed(rot_cov, dispersion))


def monte_carlo_pose_loss(
    c: Correspondences,
    target: torch.Tensor,
    generator: torch.Generator,
    samples: int = 512,
    rounds: int = 4,
    lm_iterations: int = 5,
    dispersion: float = 0.001,
) -> dict[str, torch.Tensor]:
    """the KL pose loss [B] = cost(target) + logsumexp(sample log weights), with AMIS over `rounds` rounds of
    samples / rounds draws each (upstream's 512 and 4); also the LM optimum `pose` [B x 7] and `cost_target`."""
    if samples % rounds:
        raise ValueError(f"monte_carlo_pose_loss: {samples} samples do not split into {rounds} rounds")
    pose, cov, _ = levenberg_marquardt(c, target, lm_iterations)
    proposals = [first_proposal(pose, cov, dispersion)]
    drawn: list[torch.Tensor] = []
    for i in range(rounds):
        drawn.append(proposals[i].sample(samples // rounds, generator))
        every = torch.stack(drawn)  # [i + 1 x S/r x B x 7]
        mixture = torch.stack([p.log_prob(every) for p in proposals]).logsumexp(0) - math.log(i + 1)
        log_weights = -cost(c, every) - mixture
        if i < rounds - 1:
            with torch.no_grad():
                proposals.append(refitted(every.flatten(0, 1), log_weights.detach().flatten(0, 1), dispersion))
    cost_target = cost(c, target)
    loss = cost_target + log_weights.flatten(0, 1).logsumexp(0)
    loss = torch.where(torch.isnan(loss), torch.zeros_like(loss), loss)  # upstream zeroes a NaN loss
    return {"loss": loss, "pose": pose, "cost_target": cost_target}
