"""Optimal matching layer, eq. (7)-(10), with the field-of-view head; its `loss` trains the whole pipeline.

Choices: S uses one Linear per modality (the paper's eq. (7) writes two), scaled by 1/sqrt(D) as LightGlue's so
initial logits stay moderate. A match is a mutual maximum of P (the paper's rule); `filter_threshold` (default 0)
can also demand P_ij above a value: LightGlue's 0.1 assumes peaked assignments, while edge pixels one pixel apart along
a line share nearly the same descriptor and spread P over several neighbours, so pose solvers get scores instead.
The fov filter masks 3D points after P is computed, so inference sees the same P as training.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
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
    ground_truth_matches,
    width_mismatch,
)

from .loss import edgeregnet_loss, log_assignment


def mutual_matches(log_p: torch.Tensor, threshold: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """pairs whose log_p [M2 x M3] is the maximum of its row and its column and exp(log_p) > threshold.

    -> index2d [K], index3d [K], P [K].
    """
    if log_p.numel() == 0:
        empty = torch.zeros(0, dtype=torch.long, device=log_p.device)
        return empty, empty, log_p.new_zeros(0)
    index2d = torch.arange(log_p.shape[0], device=log_p.device)
    best3d = row_argmax(log_p)  # [M2]
    best = log_p[index2d, best3d]
    column_max = log_p.amax(0)  # a column's argmax is read only where a row's best may be it: amax is vectorised,
    # argmax over dim 0 is not (24 of the matcher's ~60 ms at the CPU size)
    rows = index2d[best == column_max[best3d]]
    cols = best3d[rows]
    first = (log_p[:, cols] == column_max[cols]).byte().argmax(0)  # argmax's rule: of tied rows, the first
    mutual = rows[first == rows]
    score = best[mutual].exp()
    keep = (score > threshold) & torch.isfinite(best[mutual])
    return mutual[keep], best3d[mutual][keep], score[keep]


def row_argmax(values: torch.Tensor) -> torch.Tensor:
    """argmax of each row of values [M x N] (the first maximum); numpy's on a float32 CPU tensor, which is vectorised
    (~50x torch's on this CPU)."""
    if values.device.type == "cpu" and values.dtype == torch.float32:
        return torch.from_numpy(values.detach().numpy().argmax(1))
    return values.argmax(1)


def to_device(array: np.ndarray, device: torch.device) -> torch.Tensor:
    return torch.from_numpy(np.asarray(array)).to(device)


class OptimalMatcher(BatchedStage, Matcher):
    """Mutual maxima of the soft partial assignment P between 2D and 3D edge descriptors: EdgeRegNet's optimal
    matching layer, written in LightGlue's style. Named `lightglue`, as the shipped weights and leaderboards record
    it; `optimal-matching` is its honest alias (plugin.py)."""

    name = "lightglue"
    runtime_keys = frozenset({"filter_threshold", "fov_filter"})  # inference only: any value fits a checkpoint
    default_conf: dict[str, Any] = {
        "descriptor_dim": 256,  # D, must equal the encoders' (and the exchanger's)
        "filter_threshold": 0.0,  # a match also needs P_ij above this (LightGlue uses 0.1)
        "fov_filter": True,  # at inference, 3D points whose fov score is below 0.5 cannot match
        "eps_c": None,  # px, true-match radius for the loss; None: the frame's match_radius_px (KITTI 3, nuScenes 5)
        "weights": {"fov": 1.0, "sigma": 1.0, "P": 1.0},  # lambda_fov, lambda_sigma, lambda_P of eq. (15)
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        dim = self.conf["descriptor_dim"]
        self.proj2d, self.proj3d = nn.Linear(dim, dim), nn.Linear(dim, dim)
        self.matchability2d, self.matchability3d = nn.Linear(dim, 1), nn.Linear(dim, 1)
        self.fov = nn.Linear(dim, 1)  # the paper's 1D convolution over points, kernel 1

    def check_compatible(self, upstream: Mapping[str, Component]) -> str | None:
        return width_mismatch(self, upstream, ("descriptor_dim",))

    def forward(
        self, d2: torch.Tensor, d3: torch.Tensor, mask2d: torch.Tensor | None = None, mask3d: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, ...]:
        """d2 [B x M2 x D], d3 [B x M3 x D], keypoint masks or None -> log P [B x M2 x M3], matchability logits
        ([B x M2], [B x M3]), fov logits [B x M3]."""
        d2, d3 = d2.float(), d3.float()
        sim = (self.proj2d(d2) / self.conf["descriptor_dim"] ** 0.5) @ self.proj3d(d3).transpose(
            1, 2
        )  # scaled [M2 x D]
        z2d, z3d = self.matchability2d(d2)[..., 0], self.matchability3d(d3)[..., 0]
        return log_assignment(sim, z2d, z3d, mask2d, mask3d), z2d, z3d, self.fov(d3)[..., 0]

    def _run(self, features: Features) -> tuple[torch.Tensor, ...]:
        if features.desc2d is None or features.desc3d is None:
            raise StageError(self.label, "needs descriptors on both sides (an encoder2d and an encoder3d)")
        device = self.device
        outputs = self.batched(features.desc2d.to(device)[None], features.desc3d.to(device)[None])
        return tuple(t[0] for t in outputs)

    @torch.no_grad()
    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Matches:
        log_p, _, _, z_fov = self._run(features)
        if self.conf["fov_filter"]:
            log_p = log_p.masked_fill((z_fov < 0)[None, :], float("-inf"))  # sigmoid < 0.5
        i2d, i3d, score = mutual_matches(log_p, self.conf["filter_threshold"])
        return Matches(i2d.cpu().numpy(), i3d.cpu().numpy(), score.float().cpu().numpy())

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, device: Device = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's supervision (frame must carry T_gt): true pairs [K], their count, matchable and in-fov flags."""
        gt = ground_truth_matches(frame, kp2d, kp3d, radius_px=self.conf["eps_c"])
        arrays = {
            "pairs2d": gt.index2d,
            "pairs3d": gt.index3d,
            "num_pairs": np.int64(len(gt)),
            "matchable2d": gt.matchable2d,
            "matchable3d": gt.matchable3d,
            "in_fov3d": gt.in_fov3d,
        }
        return {k: to_device(np.asarray(v), device) for k, v in arrays.items()}

    def batch_loss(
        self,
        inputs: dict[str, torch.Tensor],
        features: Features,
        mask2d: torch.Tensor,
        mask3d: torch.Tensor,
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """eq. (15), the mean over a batch of `prepare`d frames; descriptors [B x M2 x D], [B x M3 x D]."""
        log_p, z2d, z3d, z_fov = self.batched(features.desc2d, features.desc3d, mask2d, mask3d)
        k = inputs["pairs2d"].shape[1]
        valid = torch.arange(k, device=log_p.device)[None] < inputs["num_pairs"][:, None]
        w = self.conf["weights"]
        return edgeregnet_loss(
            log_p,
            z2d,
            z3d,
            z_fov,
            pairs=(inputs["pairs2d"], inputs["pairs3d"], valid),
            matchable=(inputs["matchable2d"], inputs["matchable3d"]),
            in_fov=inputs["in_fov3d"],
            masks=(mask2d, mask3d),
            weights=(w["fov"], w["sigma"], w["P"]),
        )
