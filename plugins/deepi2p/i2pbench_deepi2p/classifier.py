"""DeepI2P's per-point classifier (Li & Lee, CVPR 2021, Sec. 3): for every 3D keypoint, is it in the camera frustum,
and which cell of the image grid does it project to. As a matcher it pairs each point classified inside with its
predicted cell's centre (a 2D keypoint), scored frustum probability x cell probability, and gives every point's
frustum probability (`Matches.frustum`, FRUSTUM_SCORES) for the inverse-projection solver (solver.py).

The head reads the fused point descriptors (fusion.py): a shared MLP (the paper's per-point PointNet, 256 and 256
wide with dropout 0.5), then a frustum logit and the cell logits. The paper's last layer has one weight vector per
cell of its fixed grid; here cell c's weight vector and bias are an MLP of c's position (positions.py), so the
logits are over whichever 2D keypoints the frame has and the pairing needs no cell arithmetic: the predicted cell
is a 2D keypoint index. The training targets (labels.py, from the true pose `Frame.T_gt` and intrinsics
`Frame.K_true`): a point's frustum label, and for a point inside, the 2D keypoint in its cell of `cell_px` pixels
(the one nearest the cell's centre, should several share a cell; none, and the point has no cell target, when its
cell holds no keypoint). The loss: binary cross-entropy of the frustum logits over every point plus cross-entropy of
the cell logits over the points inside with a target (the paper's code: a focal loss, weighted 50, for the frustum
and plain cross-entropy for the cells); a batch's loss is the mean of its frames'.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from i2pbench.api import (
    FEATURES3D,
    FRUSTUM_SCORES,
    KEYPOINTS2D,
    KEYPOINTS3D,
    MATCHES,
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
from i2pbench.layers.mlp import linear_mlp

from .labels import cell_centres, cell_of_pixels, frustum_labels, grid_labels
from .positions import feature_width, fourier_features, normalised_pixels

MASKED = -1e4  # a padded 2D keypoint's logit: exp() of it is exactly 0 next to any real logit


def trunk(widths: tuple[int, ...], dropout: float) -> nn.Sequential:
    """Linear + LayerNorm + ReLU (+ dropout) per width: the hidden layers of the paper's per-point PointNet."""
    layers: list[nn.Module] = []
    for cin, cout in zip(widths[:-1], widths[1:], strict=True):
        layers += [nn.Linear(cin, cout), nn.LayerNorm(cout), nn.ReLU(inplace=True), nn.Dropout(dropout)]
    return nn.Sequential(*layers)


def cell_targets(frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, cell_px: int) -> tuple[np.ndarray, np.ndarray]:
    """([M3] bool frustum labels, [M3] int64 index of the 2D keypoint in each inside point's cell, -1: none) under the
    frame's true pose; frame must carry T_gt."""
    if frame.T_gt is None:
        raise ValueError("frustum and cell labels need a frame with T_gt")
    size, K = frame.image_size, frame.K_true
    xyz = np.asarray(kp3d.xyz, np.float64).reshape(-1, 3)
    inside = frustum_labels(xyz, K, frame.T_gt, size)
    cells = np.where(inside, grid_labels(xyz, K, frame.T_gt, size, cell_px), -1)
    return inside, keypoint_of_cell(kp2d.uv, size, cell_px)[cells + 1]


def keypoint_of_cell(uv: np.ndarray, size: tuple[int, int], cell_px: int) -> np.ndarray:
    """[1 + cells] int64: entry 1 + c is the 2D keypoint in cell c nearest its centre (-1: none); entry 0 is -1, the
    answer for "no cell"."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    rows, cols = -(-size[1] // cell_px), -(-size[0] // cell_px)
    table = np.full(1 + rows * cols, -1, np.int64)
    cells = cell_of_pixels(uv, size, cell_px)
    inside = np.flatnonzero(cells >= 0)
    if len(inside):
        offset = np.abs(uv[inside] - cell_centres(cells[inside], size, cell_px)).max(1)
        order = inside[np.lexsort((inside, offset, cells[inside]))]  # by cell, then nearest its centre, then index
        cell, first = np.unique(cells[order], return_index=True)
        table[1 + cell] = order[first]
    return table


class DeepI2PClassifier(BatchedStage, Matcher):
    """Frustum and cell classification per 3D keypoint; matches to the predicted cells, frustum scores for all."""

    name = "deepi2p-classifier"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D, FEATURES3D})
    provides = frozenset({MATCHES, FRUSTUM_SCORES})
    runtime_keys = frozenset({"frustum_threshold"})  # inference only: any value fits a checkpoint
    default_conf: dict[str, Any] = {
        "descriptor_dim": 768,  # D, the fused point descriptors' (the exchanger's)
        "head_mlp": (256, 256),  # the shared per-point layers (the paper's)
        "dropout": 0.5,  # after each shared layer while training (the paper's)
        "cell_mlp": (64,),  # hidden widths of the MLP giving each cell's weight vector and bias from its position
        "frequencies": 6,  # Fourier frequencies of a cell's position (positions.py)
        "cell_px": 64,  # the grid's cell side in pixels, the cell-centres extractor's (training labels only)
        "frustum_threshold": 0.5,  # a point is matched when its frustum probability exceeds this
        "frustum_weight": 1.0,  # weight of the frustum BCE next to the cell cross-entropy
    }

    def __init__(self, conf: dict[str, Any] | None = None) -> None:
        super().__init__(conf)
        c = self.conf
        widths = (c["descriptor_dim"], *c["head_mlp"])
        self.trunk = trunk(widths, c["dropout"])
        self.frustum_head = nn.Linear(widths[-1], 1)
        self.cell_weights = linear_mlp((feature_width(c["frequencies"]), *c["cell_mlp"], widths[-1] + 1))

    def check_compatible(self, upstream: Mapping[str, Component]) -> str | None:
        extractor = upstream.get("extractor2d")
        theirs = getattr(extractor, "conf", {}).get("cell_px")
        if theirs is not None and theirs != self.conf["cell_px"]:
            return f"{self.label} has cell_px {self.conf['cell_px']} but {extractor.label} has cell_px {theirs}"
        return width_mismatch(self, {k: v for k, v in upstream.items() if k != "encoder2d"}, ("descriptor_dim",))

    def forward(self, d3: torch.Tensor, cell_xy: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """point descriptors d3 [B x M3 x D], cell positions [B x M2 x 2] in [0, 1] -> frustum logits [B x M3] and
        cell logits [B x M3 x M2]."""
        hidden = self.trunk(d3.float())
        weights = self.cell_weights(fourier_features(cell_xy, self.conf["frequencies"]))  # [B x M2 x (H + 1)]
        # / sqrt(H): generated weight vectors have unit-order entries, where a linear layer's start at 1 / sqrt(H)
        cells = hidden @ weights[..., :-1].transpose(1, 2) / math.sqrt(hidden.shape[-1]) + weights[..., -1][:, None]
        return self.frustum_head(hidden)[..., 0], cells

    @torch.no_grad()
    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Matches:
        if features.desc3d is None:
            raise StageError(self.label, "needs 3D descriptors (an encoder3d)")
        if len(kp3d) == 0:
            return dataclasses.replace(Matches.empty(), frustum=np.zeros(0, np.float32))
        device = self.device
        cell_xy = torch.from_numpy(normalised_pixels(kp2d.uv, frame.image_size)).to(device)
        logits, cells = self.batched(features.desc3d.to(device)[None], cell_xy[None])
        frustum = logits[0].sigmoid()
        scores = frustum.cpu().numpy().astype(np.float32)
        if len(kp2d) == 0:  # nowhere to match a point to; the frustum scores stand
            return dataclasses.replace(Matches.empty(), frustum=scores)
        inside = torch.nonzero(frustum > self.conf["frustum_threshold"])[:, 0]
        best = cells[0, inside].softmax(-1).max(-1)
        return Matches(
            best.indices.cpu().numpy().astype(np.int64),
            inside.cpu().numpy().astype(np.int64),
            (frustum[inside] * best.values).cpu().numpy().astype(np.float32),
            frustum=scores,
            radius_px=cell_half_diagonal(self.conf["cell_px"]),  # a pair is a cell: true anywhere in it
        )

    def prepare(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, device: Device = "cpu", cache: dict | None = None
    ) -> dict[str, torch.Tensor]:
        """one frame's cell positions [M2 x 2] and supervision (frame must carry T_gt): frustum labels [M3] and
        cell targets [M3] (cell_targets)."""
        inside, target = cell_targets(frame, kp2d, kp3d, self.conf["cell_px"])
        arrays = {"cell_xy": normalised_pixels(kp2d.uv, frame.image_size), "inside": inside, "cell": target}
        return {k: torch.from_numpy(np.ascontiguousarray(v)).to(device) for k, v in arrays.items()}

    def batch_loss(
        self, inputs: dict[str, torch.Tensor], features: Features, mask2d: torch.Tensor, mask3d: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """frustum_weight x frustum BCE + cell cross-entropy, each a per-frame mean, averaged over a batch of
        `prepare`d frames; descriptors [B x M3 x D], keypoint masks [B x M2], [B x M3]."""
        logits, cells = self.batched(features.desc3d, inputs["cell_xy"])
        inside, target = inputs["inside"], inputs["cell"]
        bce = F.binary_cross_entropy_with_logits(logits, inside.to(logits.dtype), reduction="none")
        frustum = per_frame_mean(bce, mask3d)
        has_cell = mask3d & (target >= 0)
        if cells.shape[-1]:
            ce = -cells.masked_fill(~mask2d[:, None], MASKED).log_softmax(-1)
            ce = ce.gather(-1, target.clamp(min=0)[..., None])[..., 0]
        else:  # no 2D keypoint in the whole batch: no cell target either
            ce = torch.zeros_like(logits)
        cell = per_frame_mean(ce, has_cell)
        total = (self.conf["frustum_weight"] * frustum + cell).mean()
        terms = {"frustum": float(frustum.detach().mean()), "cell": float(cell.detach().mean())}
        terms["inside"] = float(per_frame_mean(inside.float(), mask3d).mean())
        return total, terms


def per_frame_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """mean of values [B x M] over the entries mask [B x M] keeps -> [B] (0 for a frame with none)."""
    weights = mask.to(values.dtype)
    return (values * weights).sum(1) / weights.sum(1).clamp(min=1)
