"""DeepI2P's training loss (authors' `models/multimodal_classifier.py` foraward_pass, `models/focal_loss.py`): each
point's label is whether its projection lands in the image (coarse) and which 32 px cell it lands in (fine); the
loss is 50 x the focal loss of the coarse scores plus the cross-entropy of the fine scores over the points inside.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

COARSE_WEIGHT = 50.0  # options.py coarse_loss_alpha with is_fine_resolution
ALPHA, GAMMA = 0.5, 2.0  # FocalLoss(alpha=0.5, gamma=2)


def labels(pc: torch.Tensor, P: torch.Tensor, K: torch.Tensor, hw: tuple[int, int], cell_px: int = 32):
    """[B x 3 x N] points, P [B x 3 x 4], K [B x 3 x 3] -> (inside [B x N] bool, fine cell index [B x N])."""
    camera = P[:, :, :3] @ pc + P[:, :, 3:]
    pixels = K @ camera
    xy = pixels[:, :2] / pixels[:, 2:]
    inside = (xy[:, 0] >= 0) & (xy[:, 0] <= hw[1] - 1) & (xy[:, 1] >= 0) & (xy[:, 1] <= hw[0] - 1)
    inside &= pixels[:, 2] > 0.1
    cell = torch.floor(xy / cell_px).long()
    return inside, cell[:, 0] + cell[:, 1] * round(hw[1] / cell_px)


def focal_loss(scores: torch.Tensor, target: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """kornia's focal loss as the authors vendored it: softmax + eps (their FocalLoss sets 1e-6), a one-hot target
    + 1e-6 on every class."""
    soft = F.softmax(scores, dim=1) + eps
    one_hot = F.one_hot(target, scores.shape[1]).movedim(-1, 1).to(scores.dtype) + 1e-6
    return (one_hot * (-ALPHA * (1 - soft) ** GAMMA * torch.log(soft))).sum(dim=1).mean()


def training_loss(
    coarse: torch.Tensor, fine: torch.Tensor, inside: torch.Tensor, cell: torch.Tensor
) -> dict[str, torch.Tensor]:
    """{'coarse': 50 x focal, 'fine': cross-entropy over inside points, 'loss': their sum}."""
    coarse_loss = focal_loss(coarse, inside.long()) * COARSE_WEIGHT
    fine_loss = F.cross_entropy(fine.permute(0, 2, 1)[inside], cell[inside])
    return {"loss": coarse_loss + fine_loss, "coarse": coarse_loss, "fine": fine_loss}
