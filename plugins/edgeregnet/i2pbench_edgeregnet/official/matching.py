"""The authors' heads, matcher and loss (ESRSchao/EdgeRegNet, models/cali_glue.py:119-175, 198-261; test.py;
train_KITTI.py:69-119, 192-194).

- a shared `feature_layer` (1x1 conv without bias, BatchNorm, ReLU) on both GNN outputs; the FOV head
  `pc_score_layer` on the 3D GNN output (before `feature_layer`);
- LightGlue's MatchAssignment with ONE `final_proj` and ONE `matchability` for both modalities: similarities of the
  projections scaled by D^-1/4 each, log double softmax plus log sigmoid matchabilities, dustbins log sigmoid(-z);
  rows are 3D points, columns 2D pixels, as theirs;
- matches: mutual maxima of the log assignment without its dustbins whose probability exceeds 0 (`filter_matches(
  scores, 0.0)`), kept where the 3D point is among the `fov_top_k` highest FOV scores (test.py:97-106);
- the loss, unweighted: FOV BCE + (-mean log P over 3D points whose nearest edge pixel lies within 3 px of their
  projection) + the two matchability BCEs; the projection and its out-of-view marks (0, 0) are the authors'
  `tr3d2d` (models/vis.py:29-53, with their H = 375, W = 1250 of train_KITTI.py:181-182).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import (
    BatchedStage,
    Component,
    Device,
    Features,
    Frame,
    Keypoints2D,
    Keypoints3D,
    Matcher,
    Matches,
    StageError,
    width_mismatch,
)

from ..loss import PADDED
from .attention import ChannelNorm

BLOCK = 256  # rows or columns of the log assignment per pass without gradients: [B x 3000 x 256] stays in cache


def head(widths: tuple[int, ...]) -> nn.Sequential:
    """1x1 convs without bias (channels-last Linear), BatchNorm and ReLU after each but the last of two or more."""
    layers: list[nn.Module] = []
    for cin, cout in zip(widths[:-1], widths[1:], strict=True):
        layers += [nn.Linear(cin, cout, bias=False), ChannelNorm(cout), nn.ReLU()]
    return nn.Sequential(*(layers if len(widths) == 2 else layers[:-2]))


def log_assignment(sim: torch.Tensor, z3d: torch.Tensor, z2d: torch.Tensor) -> torch.Tensor:
    """LightGlue's `sigmoid_log_double_softmax`: sim [B x M3 x M2], matchability logits [B x M3], [B x M2] ->
    log assignment with dustbins [B x M3+1 x M2+1] (the corner 0).

    Without gradients it is written into its output BLOCK whole columns, then BLOCK whole rows at a time: a
    log-softmax of whole columns (rows) is that of the matrix, and the sums are the authors' (row + column, then
    the matchabilities: floating-point addition is commutative), so the values are the same; the six [B x M3 x M2]
    temporaries of the whole-matrix form (36 MB each at 3,000 + 3,000, too large for the allocator to keep, so
    written to fresh pages every frame) are not made."""
    if sim.requires_grad:
        return whole_log_assignment(sim, z3d, z2d)
    m3, m2 = sim.shape[1:]
    out = sim.new_empty(len(sim), m3 + 1, m2 + 1)
    inner = out[:, :m3, :m2]
    for j in range(0, m2, BLOCK):
        inner[:, :, j : j + BLOCK] = F.log_softmax(sim[:, :, j : j + BLOCK], 1)
    rows, cols = F.logsigmoid(z3d)[:, :, None], F.logsigmoid(z2d)[:, None]
    for i in range(0, m3, BLOCK):
        inner[:, i : i + BLOCK].add_(F.log_softmax(sim[:, i : i + BLOCK], 2)).add_(rows[:, i : i + BLOCK]).add_(cols)
    out[:, :m3, m2], out[:, m3, :m2], out[:, m3, m2] = F.logsigmoid(-z3d), F.logsigmoid(-z2d), 0
    return out


def whole_log_assignment(sim: torch.Tensor, z3d: torch.Tensor, z2d: torch.Tensor) -> torch.Tensor:
    """`log_assignment` as the authors write it, on whole matrices (the path with gradients)."""
    scores = F.log_softmax(sim, 2) + F.log_softmax(sim, 1) + F.logsigmoid(z3d)[:, :, None] + F.logsigmoid(z2d)[:, None]
    scores = torch.cat([scores, F.logsigmoid(-z3d)[:, :, None]], 2)
    return torch.cat([scores, F.pad(F.logsigmoid(-z2d), (0, 1))[:, None]], 1)


def filter_matches(scores: torch.Tensor, threshold: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """mutual maxima of a log assignment [M3+1 x M2+1] (dustbins left out) with exp(score) > threshold
    -> index3d [K] (ascending), index2d [K], probability [K]."""
    inner = scores[:-1, :-1]
    best, to2d = inner.max(1)
    to3d = inner.max(0).indices
    rows = torch.arange(len(inner), device=scores.device)
    keep = (to3d[to2d] == rows) & (best.exp() > threshold)
    return rows[keep], to2d[keep], best[keep].exp()


def project(xyz: torch.Tensor, K: torch.Tensor, T: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """the authors' `tr3d2d`: points [M x 3] into pixels [M x 2] under K [3 x 3], T [4 x 4], with (0, 0) for a point
    behind the camera, at a negative u or v, or beyond size (W, H) (u > W or v > H)."""
    p = (torch.cat([xyz, torch.ones_like(xyz[:, :1])], 1) @ T.T)[:, :3] @ K.T
    uv = p[:, :2] / p[:, 2:]
    w, h = size
    seen = (p >= 0).all(1) & (uv[:, 0] <= w) & (uv[:, 1] <= h)
    return torch.where(seen[:, None], uv, torch.zeros_like(uv)).nan_to_num(0.0)


def official_loss(
    out: Mapping[str, torch.Tensor], xy: torch.Tensor, uv: torch.Tensor, radius: float = 3.0
) -> dict[str, torch.Tensor]:
    """one frame's loss terms {"fov", "P", "sigma", "pairs"} from its outputs (log_assignment [M3+1 x M2+1], fov
    logits [M3], matchability logits z3d [M3], z2d [M2]), projections xy [M3 x 2] and edge pixels uv [M2 x 2]."""
    unseen = (xy == 0).all(1)
    fov = F.binary_cross_entropy(torch.sigmoid(out["fov"]), (~unseen).float())
    dist = torch.cdist(xy[None].float(), uv[None].float())[0]
    near3d, nearest = dist.min(1)
    paired3d = (near3d < radius) & ~unseen
    rows = paired3d.nonzero()[:, 0]
    picked = out["log_assignment"][rows, nearest[rows]]
    loss_p = -picked.mean() if len(rows) else picked.sum()  # no true pair: 0 (the authors' mean would be NaN)
    sigma = F.binary_cross_entropy(torch.sigmoid(out["z3d"]), paired3d.float()) + F.binary_cross_entropy(
        torch.sigmoid(out["z2d"]), (dist.min(0).values < radius).float()
    )
    return {"fov": fov, "P": loss_p, "sigma": sigma, "pairs": torch.tensor(float(len(rows)))}


class OfficialMatcher(BatchedStage, Matcher):
    """The authors' shared feature layer, FOV head and LightGlue match assignment (module docstring)."""

    name = "match-assignment-official"
    runtime_keys = frozenset({"filter_threshold", "fov_top_k"})
    default_conf: dict[str, Any] = {
        "descriptor_dim": 256,  # D, must equal the exchanger's
        "filter_threshold": 0.0,  # filter_matches(scores, 0.0) (cali_glue.py:254)
        "fov_top_k": 3000,  # matches only from the 3D points of the k highest FOV scores (test.py:97, vis3d)
        "fov_head": (256, 64, 1),  # pc_score_layer's widths after D (cali_glue.py:199)
        "loss_size": (1250, 375),  # (W, H) of the loss's projection (train_KITTI.py:181-182)
        "eps_c": 3.0,  # px, a true pair's radius in the loss (train_KITTI.py:79)
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        dim = self.conf["descriptor_dim"]
        self.feature_layer = head((dim, dim))
        self.pc_score_layer = head((dim, *self.conf["fov_head"]))
        self.final_proj, self.matchability = nn.Linear(dim, dim), nn.Linear(dim, 1)

    def check_compatible(self, upstream: Mapping[str, Component]) -> str | None:
        return width_mismatch(self, upstream, ("descriptor_dim",))

    def forward(
        self, d2: torch.Tensor, d3: torch.Tensor, mask2d: torch.Tensor | None = None, mask3d: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        """GNN outputs d2 [B x M2 x D], d3 [B x M3 x D], keypoint masks or None -> des2d, des3d (after the feature
        layer), fov logits [B x M3], sim [B x M3 x M2], matchability logits z3d [B x M3], z2d [B x M2] and the
        log_assignment [B x M3+1 x M2+1]."""
        d2, d3 = d2.float(), d3.float()
        des2d, des3d = self.feature_layer(d2), self.feature_layer(d3)
        scale = self.conf["descriptor_dim"] ** 0.25
        sim = (self.final_proj(des3d) / scale) @ (self.final_proj(des2d) / scale).transpose(1, 2)
        if mask2d is not None and mask3d is not None:
            sim = sim.masked_fill(~(mask3d[:, :, None] & mask2d[:, None, :]), PADDED)
        z3d, z2d = self.matchability(des3d)[..., 0], self.matchability(des2d)[..., 0]
        out = {"des2d": des2d, "des3d": des3d, "fov": self.pc_score_layer(d3)[..., 0], "sim": sim}
        return {**out, "z3d": z3d, "z2d": z2d, "log_assignment": log_assignment(sim, z3d, z2d)}

    @torch.no_grad()
    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Matches:
        if features.desc2d is None or features.desc3d is None:
            raise StageError(self.label, "needs descriptors on both sides (an encoder2d and an encoder3d)")
        if len(kp2d) == 0 or len(kp3d) == 0:
            return Matches.empty()
        device = self.device
        out = self.batched(features.desc2d.to(device)[None], features.desc3d.to(device)[None])
        i3d, i2d, score = filter_matches(out["log_assignment"][0], self.conf["filter_threshold"])
        fov = out["fov"][0]
        top = torch.zeros_like(fov, dtype=torch.bool)
        top[fov.topk(min(self.conf["fov_top_k"], len(fov))).indices] = True
        keep = top[i3d]
        return Matches(i2d[keep].cpu().numpy(), i3d[keep].cpu().numpy(), score[keep].float().cpu().numpy())

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, device: Device = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's supervision (frame must carry T_gt): the authors' projections xy [M3 x 2], the pixels uv."""
        K, T = (torch.from_numpy(np.asarray(a, np.float32)) for a in (frame.K_true, frame.T_gt))
        xy = project(torch.from_numpy(np.asarray(kp3d.xyz, np.float32)), K, T, tuple(self.conf["loss_size"]))
        return {"xy": xy.to(device), "uv": torch.from_numpy(np.asarray(kp2d.uv, np.float32)).to(device)}

    def batch_loss(
        self, inputs: dict[str, torch.Tensor], features: Features, mask2d: torch.Tensor, mask3d: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """the authors' loss, the mean over a batch of `prepare`d frames (each frame's own keypoints)."""
        out = self.batched(features.desc2d, features.desc3d, mask2d, mask3d)
        terms = []
        for b in range(len(mask2d)):
            n2, n3 = int(mask2d[b].sum()), int(mask3d[b].sum())
            own = {"fov": out["fov"][b, :n3], "z3d": out["z3d"][b, :n3], "z2d": out["z2d"][b, :n2]}
            scores = out["log_assignment"][b]
            own["log_assignment"] = scores[:n3, :n2]
            terms.append(official_loss(own, inputs["xy"][b, :n3], inputs["uv"][b, :n2], self.conf["eps_c"]))
        mean = {k: torch.stack([t[k] for t in terms]).mean() for k in terms[0]}
        total = mean["fov"] + mean["P"] + mean["sigma"]
        return total, {k: float(v.detach()) for k, v in mean.items()}
