"""The authors' training loss (loss.py `desc_loss`, `det_loss2`; train.py:236-263): on anchors (in-view points and
the pixels they fall in, at stride 4), a circle loss on cosine distances 1 - <f_img, f_pc> both ways (margins 0.2 /
1.8, scale 10), and the overlap scores pushed to 1 on anchors and 0 on out-of-view points and pixels; the total is
desc + 0.5 det. A pair is true when the point projects within 1 px (stride-4 pixels) of the pixel."""

from __future__ import annotations

import torch
import torch.nn.functional as F

POS_MARGIN, NEG_MARGIN, LOG_SCALE, DIST_THRES, DET_WEIGHT = 0.2, 1.8, 10.0, 1.0, 0.5  # train.py defaults


def true_pairs(pixels: torch.Tensor, points: torch.Tensor, K: torch.Tensor, T: torch.Tensor) -> torch.Tensor:
    """[P x P] 1 where anchor point j (points [3 x P], projected by K [3 x 3] after T [4 x 4]) lies within
    DIST_THRES of anchor pixel i (pixels [2 x P], stride-4 (x, y))."""
    cam = K @ (T[:3, :3] @ points + T[:3, 3:])
    xy = cam[:2] / cam[2:]
    return ((pixels[:, :, None] - xy[:, None]).square().sum(0).sqrt() <= DIST_THRES).float()


def circle_loss(img: torch.Tensor, pc: torch.Tensor, pairs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """img, pc [D x P] anchor descriptors, pairs [P x P] -> (loss, cosine distances [P x P])."""
    dist = 1 - img.t() @ pc
    pos = dist - 1e5 * (1 - pairs)
    pos_weight = (pos - POS_MARGIN).detach().clamp(min=0)
    neg = dist + 1e5 * pairs
    neg_weight = (NEG_MARGIN - neg).detach().clamp(min=0)
    pos_terms = LOG_SCALE * (pos - POS_MARGIN) * pos_weight
    neg_terms = LOG_SCALE * (NEG_MARGIN - neg) * neg_weight
    rows = F.softplus(pos_terms.logsumexp(1) + neg_terms.logsumexp(1)) / LOG_SCALE
    cols = F.softplus(pos_terms.logsumexp(0) + neg_terms.logsumexp(0)) / LOG_SCALE
    return (rows + cols).mean(), dist


def overlap_loss(
    img_in: torch.Tensor, img_out: torch.Tensor, pc_in: torch.Tensor, pc_out: torch.Tensor
) -> torch.Tensor:
    """scores of in-view anchors pushed to 1, of out-of-view samples to 0 (det_loss2)."""
    return (1 - img_in).mean() + (1 - pc_in).mean() + img_out.mean() + pc_out.mean()


def training_loss(out: dict[str, torch.Tensor], anchors: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """one frame's outputs (batch of one, channels first) and anchors (`pc_kpt_idx`, `pc_outline_idx`,
    `img_kpt_idx`, `img_outline_idx`, the cloud `pc`, stride-4 `K`, `P` moving the cloud back) -> the terms."""
    img_f = out["img_feature"][0].flatten(1)
    img_s = out["img_score"][0].flatten()
    pc_f, pc_s = out["pc_feature"][0], out["pc_score"][0, 0]
    width = out["img_feature"].shape[-1]
    idx = anchors["img_kpt_idx"]
    pixels = torch.stack([idx % width, torch.div(idx, width, rounding_mode="floor")]).float()
    points = anchors["pc"][:, anchors["pc_kpt_idx"]]
    pairs = true_pairs(pixels, points, anchors["K"], anchors["P"])
    desc, _ = circle_loss(img_f[:, idx], pc_f[:, anchors["pc_kpt_idx"]], pairs)
    det = overlap_loss(
        img_s[idx], img_s[anchors["img_outline_idx"]], pc_s[anchors["pc_kpt_idx"]], pc_s[anchors["pc_outline_idx"]]
    )
    return {"correspondence_mask": pairs, "loss_desc": desc, "loss_det": det, "loss": desc + DET_WEIGHT * det}
