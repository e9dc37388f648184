"""VP2P-Match's training loss: the authors' two functions (utils/loss.py at be76104) and the probabilistic PnP term
the paper adds, on the anchors their KITTI loader draws (models/kitti_dataset.py:338-364).

- `adapt_loss`: the adaptive-weighted circle-style loss on the dot similarities of anchor pixels and points
  (margin 0.25, scale 32). As theirs, masked entries are the similarities multiplied by 0 and then every exact 0
  is replaced by the margin's optimum, so each masked entry adds exp(0) = 1 inside its log-sum-exp;
- `det_loss`: in-view anchors' overlap scores pushed to 1, out-of-view samples' to 0;
- `pose_loss`: EPro-PnP's Monte-Carlo KL loss (i2pbench.layers.epropnp), per correspondence in the total, on
  correspondences made differentiable:
  each anchor pixel's 3D point is the softmax-weighted (similarity / temperature) mean of the candidate points
  (the in-view anchors and the out-of-view draws), weighted by the pixel's overlap score times the candidates'
  expected score. The authors released no training script (their issue #2): how they fed EPro-PnP is not
  published, so this construction, and the weights of the three terms, are i2pbench's (docs/methods.md).

Anchors, from the frame's true pose (`anchors`): the cloud projected by K at a quarter of the crop's into the
stride-4 map; points landing inside are in view; up to `num_kpt` of them (a seeded permutation), up to `num_kpt`
out-of-view points, each in-view anchor's cell, up to `num_kpt` cells no point lands in; a pixel-point pair is
true when the point projects within `dist_thres` (1 cell) of the cell's corner (CorrI2P's train.py:246-250, which
VP2P-Match's loader and loss follow).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from scipy.spatial.transform import Rotation

from i2pbench.layers.epropnp import Correspondences, adaptive_delta, monte_carlo_pose_loss

# the loss's defaults; the weights are i2pbench's choice (module docstring), the rest the authors' or EPro-PnP's
LOSS_CONF: dict[str, Any] = {
    "margin": 0.25,  # utils/loss.py adapt_loss
    "gamma": 32.0,  # utils/loss.py adapt_loss
    "num_kpt": 512,  # run_kitti.py --num_kpt: anchors per side
    "dist_thres": 1.0,  # run_kitti.py --dist_thres, stride-4 cells
    "det_weight": 0.5,  # chosen: CorrI2P train.py's weight of the same det loss (VP2P-Match's loader is theirs)
    "pose_weight": 0.02,  # chosen: EPro-PnP's Monte-Carlo loss weight (EPro-PnP-6DoF epropnp_basic.yaml), on the
    # KL per correspondence (EPro-PnP's weights are normalised over the points, these per-point scores are not)
    "pose_temperature": 1 / 32,  # chosen: the similarity scale adapt_loss trains with (1 / gamma)
    "pose_samples": 512,  # EPro-PnP: Monte-Carlo samples
    "pose_rounds": 4,  # EPro-PnP: AMIS rounds
    "pose_lm_iterations": 5,  # EPro-PnP-6DoF train.py's LMSolver
    "pose_relative_delta": 0.1,  # EPro-PnP-6DoF train.py's AdaptiveHuberPnPCost
    "pose_min_anchors": 6,  # fewer in-view anchors: no pose term for the frame (PnP needs six)
}


def adapt_loss(
    img: torch.Tensor, pc: torch.Tensor, mask: torch.Tensor, margin: float = 0.25, gamma: float = 32.0
) -> tuple[torch.Tensor, torch.Tensor]:
    """img [B x D x P], pc [B x D x Q] descriptors, mask [B x P x Q] true pairs (0/1) -> (the mean of each pixel's
    loss plus the mean of each point's, dot similarities [B x P x Q]); the authors' function when P == Q."""
    sim = torch.einsum("bdp,bdq->bpq", img, pc)
    pos, neg = sim * mask, sim * (1 - mask)
    alpha_p = (1 + margin - pos.detach()).clamp(min=0)
    alpha_n = (neg.detach() + margin).clamp(min=0)
    pos = torch.where(pos == 0, torch.full_like(pos, 1 - margin), pos)
    neg = torch.where(neg == 0, torch.full_like(neg, margin), neg)
    logit_p = -gamma * alpha_p * (pos - (1 - margin))
    logit_n = gamma * alpha_n * (neg - margin)
    per_pixel = F.softplus(logit_p.logsumexp(-1) + logit_n.logsumexp(-1))
    per_point = F.softplus(logit_p.logsumexp(-2) + logit_n.logsumexp(-2))
    return per_pixel.mean() + per_point.mean(), sim


def det_loss(img_in: torch.Tensor, img_out: torch.Tensor, pc_in: torch.Tensor, pc_out: torch.Tensor) -> torch.Tensor:
    """scores of in-view anchors pushed to 1, of out-of-view samples to 0 (utils/loss.py det_loss)."""
    return (1 - img_in).mean() + (1 - pc_in).mean() + img_out.mean() + pc_out.mean()


def cell_camera(K: np.ndarray, width: int, height: int, crop: Mapping[str, Any], cell_px: int) -> np.ndarray:
    """K [3 x 3] of the frame -> K of the crop's stride-`cell_px` map (the authors' K_4): cell (x, y)'s corner is
    the frame's pixel (step x + dx / scale, step y + dy / scale + top rows), step = cell_px / scale."""
    from i2pbench.layers.peer_inputs import crop_offsets

    dx, dy = crop_offsets(width, height, crop)
    step, scale = cell_px / crop["scale"], crop["scale"]
    to_cells = np.array(
        [[1 / step, 0, -dx / scale / step], [0, 1 / step, -(dy / scale + crop.get("top_rows", 0)) / step], [0, 0, 1]]
    )
    return to_cells @ np.asarray(K, np.float64)


def pose_vector(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """rotation [3 x 3] and translation [3] -> [7]: translation, unit quaternion (w, x, y, z)."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.concatenate([t, [w, x, y, z]])


def anchors(
    pc: np.ndarray, K4: np.ndarray, R: np.ndarray, t: np.ndarray, cells: tuple[int, int], num_kpt: int,
    dist_thres: float, rng: np.random.Generator,
) -> dict[str, np.ndarray]:  # fmt: skip
    """the authors' anchors (module docstring) of cloud pc [3 x N] seen by pose (R, t) and K4 on a (w, h) map."""
    w, h = cells
    proj = K4 @ (R @ pc + t[:, None])
    xy = np.floor(proj[:2] / proj[2:])
    inside = (xy[0] >= 0) & (xy[0] <= w - 1) & (xy[1] >= 0) & (xy[1] <= h - 1) & (proj[2] > 0)
    pc_in = np.flatnonzero(inside)
    pc_in = pc_in[rng.permutation(len(pc_in))[:num_kpt]]
    pc_out = np.flatnonzero(~inside)
    pc_out = pc_out[rng.permutation(len(pc_out))[:num_kpt]]
    seen = np.zeros(w * h, bool)
    seen[(xy[1, inside] * w + xy[0, inside]).astype(np.int64)] = True
    img_in = (xy[1, pc_in] * w + xy[0, pc_in]).astype(np.int64)
    img_out = np.flatnonzero(~seen)
    img_out = img_out[rng.permutation(len(img_out))[:num_kpt]]
    cell_xy = np.stack([img_in % w, img_in // w], 1).astype(np.float32)
    projected = (proj[:2, pc_in] / proj[2:, pc_in]).T
    pairs = np.linalg.norm(cell_xy[:, None] - projected[None], axis=-1) <= dist_thres
    return {
        "pc_kpt_idx": pc_in, "pc_outline_idx": pc_out, "img_kpt_idx": img_in, "img_outline_idx": img_out,
        "img_xy": cell_xy, "correspondence": pairs.astype(np.float32),
    }  # fmt: skip


def soft_correspondences(
    out: Mapping[str, torch.Tensor], sup: Mapping[str, torch.Tensor], pc: torch.Tensor, temperature: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """each anchor pixel's 3D point [P x 3] (softmax over candidates of similarity / temperature) and its weight
    [P x 2] (pixel score x the candidates' expected score)."""
    candidates = torch.cat([sup["pc_kpt_idx"], sup["pc_outline_idx"]])
    pixel_feat = out["pixel_feat"].flatten(1)[:, sup["img_kpt_idx"]]
    assign = (pixel_feat.t() @ out["point_feat"][:, candidates] / temperature).softmax(-1)
    x3d = assign @ pc[:, candidates].t()
    weight = out["img_score"].flatten()[sup["img_kpt_idx"]] * (assign @ out["pc_score"][0, candidates])
    return x3d, weight[:, None].expand(-1, 2)


def pose_loss(
    out: Mapping[str, torch.Tensor], sup: Mapping[str, torch.Tensor], pc: torch.Tensor, conf: Mapping[str, Any]
) -> torch.Tensor:
    """EPro-PnP's KL loss of one frame's true pose `sup["pose"]` under its soft correspondences (in cells), computed
    in float64 whatever the network's precision: on near-degenerate soft points (an untrained network's collapse
    towards one plane) float32's LM and proposals gave 6-25 where float64 gives 4.08 +- 0.002 (docs/methods.md)."""
    with torch.autocast(pc.device.type, enabled=False):
        x3d, w2d = soft_correspondences({k: v.double() for k, v in out.items()}, sup, pc.double(),
                                        float(conf["pose_temperature"]))  # fmt: skip
        x2d = sup["img_xy"].double()
        delta = adaptive_delta(x2d[None], w2d[None], float(conf["pose_relative_delta"]))
        c = Correspondences(x3d[None], x2d[None], w2d[None], sup["K4"][None].double(), delta)
        generator = torch.Generator(device="cpu").manual_seed(int(sup["seed"]))
        return monte_carlo_pose_loss(
            c, sup["pose"][None].double(), generator, int(conf["pose_samples"]), int(conf["pose_rounds"]),
            int(conf["pose_lm_iterations"]),
        )["loss"][0].to(out["pc_score"].dtype)  # fmt: skip


def frame_loss(
    out: Mapping[str, torch.Tensor], sup: Mapping[str, torch.Tensor], pc: torch.Tensor, conf: Mapping[str, Any]
) -> dict[str, torch.Tensor]:
    """one frame's terms: network outputs without the batch dim, its anchors `sup`, its cloud pc [3 x N]."""
    img_score, pc_score = out["img_score"].flatten(), out["pc_score"][0]
    pc_in, img_in = sup["pc_kpt_idx"], sup["img_kpt_idx"]
    zero = img_score.sum() * 0
    terms = {"det": zero, "desc": zero, "pose": zero}
    if len(pc_in):
        pixel_feat, point_feat = out["pixel_feat"].flatten(1)[None, :, img_in], out["point_feat"][None, :, pc_in]
        margin, gamma = float(conf["margin"]), float(conf["gamma"])
        terms["desc"], _ = adapt_loss(pixel_feat, point_feat, sup["correspondence"][None], margin, gamma)
        terms["det"] = det_loss(img_score[img_in], img_score[sup["img_outline_idx"]], pc_score[pc_in],
                                pc_score[sup["pc_outline_idx"]])  # fmt: skip
    if len(pc_in) >= int(conf["pose_min_anchors"]) and float(conf["pose_weight"]) > 0:
        terms["pose"] = pose_loss(out, sup, pc, conf) / len(pc_in)
    weighted = float(conf["det_weight"]) * terms["det"] + float(conf["pose_weight"]) * terms["pose"]
    terms["loss"] = terms["desc"] + weighted
    return terms
