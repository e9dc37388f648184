"""train.py's training loss (train.py:233-283, model/loss.py) on one frame: the coarse circle-style descriptor loss
over the loader's super-point / super-pixel anchors (`desc_loss`), the overlap BCE of the anchors' and the outliers'
scores (`overlap_loss`), the fine circle loss of each anchor's point descriptor against its 4 x 4 patch
(`fine_circle_loss`), and their plain sum."""

from __future__ import annotations

import torch
import torch.nn.functional as F

POS_MARGIN, NEG_MARGIN, LOG_SCALE = 0.2, 1.8, 10.0  # options.py pos_margin, neg_margin; loss.py log_scale
DIST_THRES = 1.0  # options.py dist_thres: a true coarse pair projects within 1 stride-8 cell
CIRCLE_MARGIN, CIRCLE_GAMMA = 0.2, 5.0  # loss.py fine_circle_loss m, gamma


def desc_loss(img: torch.Tensor, pc: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """descriptors [C x k] of k super-pixels and k super-points, mask [k x k] of true pairs -> the mean over rows and
    columns of softplus(LSE of weighted positive + negative terms) / LOG_SCALE (loss.py desc_loss)."""
    dists = 1 - (img[:, :, None] * pc[:, None]).sum(0)
    pos = dists - 1e5 * (1 - mask)
    neg = dists + 1e5 * mask
    pos_term = LOG_SCALE * (pos - POS_MARGIN) * (pos - POS_MARGIN).detach().clamp(min=0)
    neg_term = LOG_SCALE * (NEG_MARGIN - neg) * (NEG_MARGIN - neg).detach().clamp(min=0)
    rows = F.softplus(pos_term.logsumexp(-1) + neg_term.logsumexp(-1)) / LOG_SCALE
    cols = F.softplus(pos_term.logsumexp(-2) + neg_term.logsumexp(-2)) / LOG_SCALE
    return (rows + cols).mean()


def overlap_loss(inside: torch.Tensor, outside: torch.Tensor) -> torch.Tensor:
    """binary cross-entropy of super-point scores, 1 for those seen by the camera, 0 for the others."""
    scores = torch.cat([inside, outside])
    return F.binary_cross_entropy(scores, torch.cat([torch.ones_like(inside), torch.zeros_like(outside)]))


def fine_circle_loss(patches: torch.Tensor, points: torch.Tensor, true_cell: torch.Tensor) -> torch.Tensor:
    """patches [n x C x 4 x 4], point descriptors [n x C], the true pixel of each patch [n] (row * 4 + column) ->
    the circle loss of the cosine similarities (loss.py fine_circle_loss)."""
    similarity = F.cosine_similarity(patches.flatten(2), points[:, :, None], dim=1)  # n x 16
    pos = F.one_hot(true_cell.long(), similarity.shape[1]).to(similarity.dtype)
    neg = 1 - pos
    sp, sn = similarity * pos, similarity * neg
    ap = (pos * (1 + CIRCLE_MARGIN) - sp.detach()).clamp(min=0)
    an = (sn.detach() + neg * CIRCLE_MARGIN).clamp(min=0)
    loss_p = (torch.exp(-ap * (sp - pos * (1 - CIRCLE_MARGIN)) * CIRCLE_GAMMA) * pos).sum(-1)
    loss_n = (torch.exp(an * (sn - neg * CIRCLE_MARGIN) * CIRCLE_GAMMA) * neg).sum(-1)
    return torch.log(1 + loss_n * loss_p).mean()


def coarse_mask(img_index: torch.Tensor, xyz: torch.Tensor, K_4: torch.Tensor, P: torch.Tensor, width: int):
    """[k x k] true pairs: super-pixel i (flat index on the stride-8 map of `width` columns) and super-point j
    [3 x k] moved by P and projected with K_4 within DIST_THRES cells."""
    pixel = torch.stack([img_index % width, img_index.div(width, rounding_mode="floor")]).to(xyz.dtype)
    projected = K_4 @ (P[:3, :3] @ xyz + P[:3, 3:])
    xy = projected[:2] / projected[2:]
    return ((pixel[:, :, None] - xy[:, None]).pow(2).sum(0).sqrt() <= DIST_THRES).to(xyz.dtype)


def training_loss(outputs: tuple, anchors: dict[str, torch.Tensor], nodes: torch.Tensor) -> dict[str, torch.Tensor]:
    """the network's 'train'/'val' outputs, the loader's anchors (pc_kpt_idx, pc_outline_idx, coarse_img_kpt_idx,
    K_4, P, fine_xy, fine_center_kpt_coors) and the super-points [N4 x 3] -> train.py's terms and their sum."""
    img_features, pc_features, _, pc_score, patches, fine_pc = outputs[:6]
    kpt = anchors["pc_kpt_idx"]
    flat = img_features.reshape(img_features.shape[1], -1)
    img_inline = flat[:, anchors["coarse_img_kpt_idx"]]
    mask = coarse_mask(anchors["coarse_img_kpt_idx"], nodes.T[:, kpt], anchors["K_4"], anchors["P"],
                       img_features.shape[-1])  # fmt: skip
    relative = anchors["fine_xy"] - anchors["fine_center_kpt_coors"] + 2
    terms = {
        "loss_desc": desc_loss(img_inline, pc_features[:, kpt], mask),
        "loss_coarse": overlap_loss(pc_score[0, 0, kpt], pc_score[0, 0, anchors["pc_outline_idx"]]),
        "loss_fine": fine_circle_loss(patches, fine_pc, relative[1] * 4 + relative[0]),
    }
    return terms | {"loss": terms["loss_desc"] + terms["loss_coarse"] + terms["loss_fine"],
                    "correspondence_mask": mask}  # fmt: skip
