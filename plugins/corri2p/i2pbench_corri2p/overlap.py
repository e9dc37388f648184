"""CorrI2P's overlap scores (the rest of its overlapping region detector) and correspondences, with its loss.

Heads on the exchanged features give every pixel and point an overlap score (the sigmoid of a logit: does it see
the other modality) and a 64-wide L2-normalised matching descriptor. At inference, the pixels and points whose score
exceeds `score_threshold` (the paper's 0.9) are paired by descriptor similarity; the pose solver (EPnP in RANSAC)
follows. Training minimises the circle loss on true pairs plus `overlap_weight` (the paper's 0.5) times the overlap
loss (loss.py).

What differs, and why:
- pairing: the paper keeps, for every selected point, its most similar selected pixel; `mutual: true` (the default
  here) keeps only pairs that are each other's most similar, which gives the solver fewer, cleaner matches
  (`mutual: false` is the paper's rule); Matches carry the pair's cosine similarity as their score;
- the overlap loss is a class-balanced binary cross-entropy (the mean over overlapping keypoints plus the mean over
  the others); the paper's code penalises (1 - s) and s over 512 sampled keypoints of each class, the same balance
  with a linear rather than logarithmic penalty;
- a pair is true when the point projects anywhere in the pixel's grid cell (`Matches.radius_px`: the cell's half
  diagonal, 11.31 px at the CPU size's stride 16, 5.66 px at the paper size's stride 8), the resolution at which
  the paper defines its pairs and overlap; eps_c (3 px) would credit only the cell's centre;
- the heads are Linear + ReLU layers normalised over each frame's keypoints (layers/frame_norm.py), the paper's 1x1
  convolutions with BatchNorm with one frame's statistics instead of a batch's.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

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
    cell_half_diagonal,
    width_mismatch,
)
from i2pbench.layers.frame_norm import FrameMLP

from .loss import anchor_pairs, balanced_bce, circle_loss, overlap_labels


def mutual_nearest(sim: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(rows, cols) of the entries of sim [R x C] that are the maximum of both their row and their column."""
    if sim.numel() == 0:
        empty = torch.zeros(0, dtype=torch.long, device=sim.device)
        return empty, empty
    best_col = sim.argmax(1)
    rows = torch.arange(sim.shape[0], device=sim.device)
    keep = sim.argmax(0)[best_col] == rows
    return rows[keep], best_col[keep]


def nearest_to_each_column(sim: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(rows, cols): every column of sim [R x C] with its most similar row (the paper's rule, points -> pixels)."""
    if sim.numel() == 0:
        empty = torch.zeros(0, dtype=torch.long, device=sim.device)
        return empty, empty
    return sim.argmax(0), torch.arange(sim.shape[1], device=sim.device)


def candidates(scores: torch.Tensor, threshold: float, cap: int | None) -> torch.Tensor:
    """indices of the scores [M] above threshold, the `cap` highest of them when set, in index order."""
    keep = torch.nonzero(scores > threshold)[:, 0]
    if cap is not None and len(keep) > cap:
        keep = keep[scores[keep].topk(int(cap)).indices].sort().values
    return keep


class CorrI2PMatcher(BatchedStage, Matcher):
    """Overlap scores on both sides, then pairs of high-score pixels and points by descriptor similarity."""

    name = "corri2p-overlap"
    revision = 1  # 1: pairs carry the grid cell's radius (results cached before were judged within eps_c)
    runtime_keys = frozenset({"score_threshold", "max_candidates", "mutual"})  # inference only: any value fits
    default_conf: dict[str, Any] = {
        "descriptor_dim": 640,  # D, must equal the exchanger's (or the encoders')
        "match_dim": 64,  # width of the matching descriptors (the paper's 64)
        "head_mlp": (128,),  # hidden widths of the four heads (descriptor and score, per modality)
        "score_threshold": 0.9,  # a keypoint is matched only if its overlap score exceeds this (the paper's 0.9)
        "max_candidates": None,  # at most this many highest-scoring keypoints per side (None: all above threshold)
        "mutual": True,  # mutual nearest neighbours; False: each point's most similar pixel (the paper's rule)
        "pair_radius_px": 8.0,  # a point projecting within this of a pixel is a true pair (one stride-8 cell)
        "overlap_window_px": 4.0,  # a pixel overlaps if a point projects within this (each axis): its stride-8 cell
        "num_anchors": 512,  # 3D keypoints with a true pair the circle loss uses per frame (the paper's 512)
        "pos_margin": 0.2,  # circle loss: positives pushed below this distance 1 - cos (the paper's 0.2)
        "neg_margin": 1.8,  # circle loss: negatives pushed above this (the paper's 1.8)
        "gamma": 10.0,  # circle loss scale (the paper's 10)
        "overlap_weight": 0.5,  # weight of the overlap loss next to the circle loss (the paper's 0.5)
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        d, hidden, out = self.conf["descriptor_dim"], tuple(self.conf["head_mlp"]), self.conf["match_dim"]
        self.desc2d, self.desc3d = FrameMLP((d, *hidden, out)), FrameMLP((d, *hidden, out))
        self.score2d, self.score3d = FrameMLP((d, *hidden, 1)), FrameMLP((d, *hidden, 1))

    def check_compatible(self, upstream: Mapping[str, Component]) -> str | None:
        return width_mismatch(self, upstream, ("descriptor_dim",))

    def forward(
        self, d2: torch.Tensor, d3: torch.Tensor, mask2d: torch.Tensor | None = None, mask3d: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, ...]:
        """d2 [... x M2 x D], d3 [... x M3 x D] (keypoint masks [... x M2], [... x M3], None: no padding) -> overlap
        logits ([... x M2], [... x M3]) and normalised matching descriptors ([... x M2 x E], [... x M3 x E])."""
        d2, d3 = d2.float(), d3.float()
        f2, f3 = F.normalize(self.desc2d(d2, mask2d), dim=-1), F.normalize(self.desc3d(d3, mask3d), dim=-1)
        return self.score2d(d2, mask2d)[..., 0], self.score3d(d3, mask3d)[..., 0], f2, f3

    @torch.no_grad()
    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Matches:
        if features.desc2d is None or features.desc3d is None:
            raise StageError(self.label, "needs descriptors on both sides (an encoder2d and an encoder3d)")
        device = self.device
        z2, z3, f2, f3 = self.batched(features.desc2d.to(device), features.desc3d.to(device))
        threshold, cap = self.conf["score_threshold"], self.conf["max_candidates"]
        keep2, keep3 = candidates(z2.sigmoid(), threshold, cap), candidates(z3.sigmoid(), threshold, cap)
        sim = f2[keep2] @ f3[keep3].T
        rows, cols = mutual_nearest(sim) if self.conf["mutual"] else nearest_to_each_column(sim)
        return Matches(
            keep2[rows].cpu().numpy().astype(np.int64),
            keep3[cols].cpu().numpy().astype(np.int64),
            sim[rows, cols].float().cpu().numpy().astype(np.float32),
            radius_px=cell_half_diagonal(2 * self.conf["overlap_window_px"]),  # a pixel stands for its grid cell
        )

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, device: Device = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's supervision (frame must carry T_gt): overlap labels [M2], [M3], the circle loss's anchors
        (anchor2d [A2], anchor3d [A3], positive [A2 x A3], their counts) and the frame's number of true pairs."""
        overlap2d, overlap3d = overlap_labels(frame, kp2d, kp3d, self.conf["overlap_window_px"])
        anchors = anchor_pairs(frame, kp2d, kp3d, self.conf["pair_radius_px"], self.conf["num_anchors"])
        arrays = {
            "overlap2d": overlap2d,
            "overlap3d": overlap3d,
            **anchors,
            "num_anchor2d": np.int64(len(anchors["anchor2d"])),
            "num_anchor3d": np.int64(len(anchors["anchor3d"])),
        }
        return {k: torch.from_numpy(np.asarray(v)).to(device) for k, v in arrays.items()}

    def batch_loss(
        self, inputs: dict[str, torch.Tensor], features: Features, mask2d: torch.Tensor, mask3d: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """circle + overlap_weight x overlap, the mean over a batch of `prepare`d frames; descriptors
        [B x M2 x D], [B x M3 x D], keypoint masks [B x M2], [B x M3]."""
        z2, z3, f2, f3 = self.batched(features.desc2d, features.desc3d, mask2d, mask3d)
        overlap = balanced_bce(z2, inputs["overlap2d"], mask2d) + balanced_bce(z3, inputs["overlap3d"], mask3d)
        a2, a3 = inputs["anchor2d"], inputs["anchor3d"]
        dist = 1 - gather_rows(f2, a2) @ gather_rows(f3, a3).transpose(1, 2)  # [B x A2 x A3]
        valid = (
            torch.arange(a2.shape[1], device=a2.device)[None] < inputs["num_anchor2d"][:, None],
            torch.arange(a3.shape[1], device=a3.device)[None] < inputs["num_anchor3d"][:, None],
        )
        c = self.conf
        circle = circle_loss(dist, inputs["positive"], valid, (c["pos_margin"], c["neg_margin"]), c["gamma"])
        total = (circle + c["overlap_weight"] * overlap).mean()
        terms = {"circle": float(circle.detach().mean()), "overlap": float(overlap.detach().mean())}
        terms["pairs"] = float(inputs["num_pairs"].float().mean())
        return total, terms


def gather_rows(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """rows of values [B x M x C] at index [B x K] -> [B x K x C]."""
    return values.gather(1, index[..., None].expand(-1, -1, values.shape[-1]))
