"""EdgeRegNet's loss, eq. (11)-(15): field-of-view BCE + matchability BCE + negative log assignment of true pairs."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def log_assignment(sim: torch.Tensor, z2d: torch.Tensor, z3d: torch.Tensor) -> torch.Tensor:
    """log P of eq. (10) from similarities sim [M2 x M3] and matchability logits z2d [M2], z3d [M3] -> [M2 x M3].

    log P_ij = log sigma2D_i + log sigma3D_j + log softmax_k(S_kj)_i + log softmax_k(S_ik)_j, in log space throughout.
    """
    return F.logsigmoid(z2d)[:, None] + F.logsigmoid(z3d)[None, :] + sim.log_softmax(0) + sim.log_softmax(1)


def edgeregnet_loss(
    log_p: torch.Tensor,
    z2d: torch.Tensor,
    z3d: torch.Tensor,
    z_fov: torch.Tensor,
    pairs: tuple[torch.Tensor, torch.Tensor],
    matchable: tuple[torch.Tensor, torch.Tensor],
    in_fov: torch.Tensor,
    weights: tuple[float, float, float] = (1.0, 1.0, 1.0),
) -> tuple[torch.Tensor, dict[str, float]]:
    """total loss and its terms {"fov", "sigma", "P", "pairs"}.

    log_p [M2 x M3]; logits z2d [M2], z3d [M3], z_fov [M3]; pairs: (index2d [K], index3d [K]) true matches;
    matchable: ([M2], [M3]) bool; in_fov [M3] bool; weights: (w_fov, w_sigma, w_P). With no true pair, L_P is 0
    (and "pairs" is 0): the frame still trains the field-of-view and matchability heads.
    """
    w_fov, w_sigma, w_p = weights
    l_fov = F.binary_cross_entropy_with_logits(z_fov, in_fov.float()) if z_fov.numel() else z_fov.sum()
    l_sigma = sum(
        (F.binary_cross_entropy_with_logits(z, m.float()) if z.numel() else z.sum())
        for z, m in zip((z2d, z3d), matchable, strict=True)
    )
    i2d, i3d = pairs
    l_p = -log_p[i2d, i3d].mean() if i2d.numel() else log_p.sum() * 0.0  # keeps the graph for an empty frame
    total = w_fov * l_fov + w_sigma * l_sigma + w_p * l_p
    terms = {name: float(t.detach()) for name, t in (("fov", l_fov), ("sigma", l_sigma), ("P", l_p))}
    terms["pairs"] = float(i2d.numel())
    return total, terms
