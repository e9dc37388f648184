"""CorrI2P's supervision (the paper's loss): ground-truth labels from T_gt, the circle loss on descriptors of true
pixel-point pairs, and the overlap (detector) loss on both sides' overlap scores.

Labels, from the 3D keypoints projected with the true camera (`Frame.K_true`, `Frame.T_gt`):
- a 3D keypoint overlaps the image if it projects in front of the camera and inside the image (the paper's point
  label);
- a 2D keypoint overlaps the point cloud if some in-image point of the scan (every finite return, not only the 3D
  keypoints) projects into the square window of half-width `window_px` around it (with the grid extractor's stride s
  and window s / 2: into its cell), the paper's pixel label, whose points are all its 40,960. Counting only the 3D
  keypoints would make the label a sampling accident: 4,096 random keypoints of a synthetic scan, ~14% in view,
  mark 23% of a stride-16 grid where the whole scan marks 58%, so a third of the pixels would be labelled
  "no overlap" beside identical neighbours labelled "overlap", and no pixel score could become confident;
- a pixel and a point are a true pair if the point projects within `radius_px` of the pixel (the paper: one cell of
  the feature map, 8 px of a full-size KITTI image).
The circle loss (Sun et al., CVPR 2020, in the distance form CorrI2P uses) runs on anchors: up to `num_anchors`
3D keypoints with a true partner (the paper's 512 in-view points), drawn by a generator seeded by the frame and its
transform, and the nearest 2D keypoint of each; a batch is the mean of its frames.
"""

from __future__ import annotations

import zlib

import numpy as np
import torch
import torch.nn.functional as F
from scipy.spatial import cKDTree

from i2pbench.api import Frame, Keypoints2D, Keypoints3D, ground_truth_matches, in_image, project

MASKED = -1e4  # stands for a masked entry inside a log-sum-exp: exp() is exactly 0 next to any real term, and unlike
# -inf a row with no real entry gives a finite value (its loss is then softplus(-1e4) = 0, with zero gradient)


def overlap_labels(
    frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, window_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """([M2] bool: some in-image point of the scan projects within the window around the pixel, [M3] bool: the 3D
    keypoint projects inside the image); frame must carry T_gt."""
    if frame.T_gt is None:
        raise ValueError("overlap labels need a frame with T_gt")
    points = np.asarray(frame.points[:, :3], np.float64)
    uv, front = project(frame.K_true, frame.T_gt, points[np.isfinite(points).all(1)])
    seen = uv[in_image(uv, front, frame.image_size)]
    overlap2d = np.zeros(len(kp2d), bool)
    if len(seen) and len(kp2d):
        distance, _ = cKDTree(seen).query(np.asarray(kp2d.uv, np.float64), k=1, p=np.inf)
        overlap2d = distance <= window_px
    uv3, front3 = project(frame.K_true, frame.T_gt, np.asarray(kp3d.xyz, np.float64).reshape(-1, 3))
    return overlap2d, in_image(uv3, front3, frame.image_size)


def sample_seed(frame: Frame) -> int:
    """a seed for one training sample: its frame and its transform (a fresh transform draws fresh anchors)."""
    identity = zlib.crc32(f"{frame.dataset}/{frame.frame_id}".encode())
    return zlib.crc32(np.ascontiguousarray(frame.T_gt, np.float64).tobytes(), identity)


def anchor_pairs(
    frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, radius_px: float, num_anchors: int
) -> dict[str, np.ndarray]:
    """the circle loss's anchors: 3D keypoints with a true partner (at most `num_anchors`, seeded subset), the
    nearest 2D keypoint of each (each once), which of those pairs are true [A2 x A3], and the frame's true pairs."""
    gt = ground_truth_matches(frame, kp2d, kp3d, radius_px=radius_px)
    pick = np.arange(len(gt))
    if len(pick) > num_anchors:
        pick = np.sort(np.random.default_rng(sample_seed(frame)).choice(len(pick), num_anchors, replace=False))
    anchor3d, anchor2d = gt.index3d[pick], np.unique(gt.index2d[pick])
    uv3, _ = project(frame.K_true, frame.T_gt, np.asarray(kp3d.xyz, np.float64)[anchor3d].reshape(-1, 3))
    distance = np.linalg.norm(np.asarray(kp2d.uv, np.float64)[anchor2d][:, None] - uv3[None], axis=-1)
    return {
        "anchor2d": anchor2d.astype(np.int64),
        "anchor3d": anchor3d.astype(np.int64),
        "positive": distance.reshape(len(anchor2d), len(anchor3d)) < radius_px,
        "num_pairs": np.int64(len(gt)),
    }


def masked_logsumexp(x: torch.Tensor, mask: torch.Tensor, dim: int) -> torch.Tensor:
    return x.masked_fill(~mask, MASKED).logsumexp(dim)


def anchor_losses(
    dist: torch.Tensor,
    positive: torch.Tensor,
    negative: torch.Tensor,
    dim: int,
    margins: tuple[float, float],
    gamma: float,
) -> torch.Tensor:
    """circle loss of each anchor, reducing dist [B x A2 x A3] over `dim`:
    softplus(LSE_p gamma a_p (d_p - m_p) + LSE_n gamma a_n (m_n - d_n)) / gamma, a_p = [d_p - m_p]+, a_n = [m_n - d_n]+
    (the weights a are constants, as in the circle loss)."""
    pos_margin, neg_margin = margins
    pos = gamma * (dist - pos_margin).clamp(min=0).detach() * (dist - pos_margin)
    neg = gamma * (neg_margin - dist).clamp(min=0).detach() * (neg_margin - dist)
    return F.softplus(masked_logsumexp(pos, positive, dim) + masked_logsumexp(neg, negative, dim)) / gamma


def circle_loss(
    dist: torch.Tensor,
    positive: torch.Tensor,
    valid: tuple[torch.Tensor, torch.Tensor],
    margins: tuple[float, float] = (0.2, 1.8),
    gamma: float = 10.0,
) -> torch.Tensor:
    """per-frame circle loss [B]: the mean over the 2D anchors (each against the 3D anchors) plus the mean over the
    3D anchors (each against the 2D ones), as the paper's two directions.

    dist [B x A2 x A3] descriptor distances 1 - cos; positive [B x A2 x A3] bool true pairs; valid ([B x A2],
    [B x A3]) anchors that are not padding. Only anchors with a true pair count; a frame with none gives 0.
    """
    pairs = valid[0][:, :, None] & valid[1][:, None, :]
    positive = positive & pairs
    negative = pairs & ~positive
    rows = anchor_losses(dist, positive, negative, 2, margins, gamma)  # [B x A2]
    cols = anchor_losses(dist, positive, negative, 1, margins, gamma)  # [B x A3]
    has_row, has_col = positive.any(2), positive.any(1)
    return (rows * has_row).sum(1) / has_row.sum(1).clamp(min=1) + (cols * has_col).sum(1) / has_col.sum(1).clamp(min=1)


def balanced_bce(logits: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """per-frame BCE [B] of logits [B x M] against bool target, the mean over the overlapping keypoints plus the mean
    over the others (the paper samples as many of each), masked; a class with no member adds 0."""
    bce = F.binary_cross_entropy_with_logits(logits, target.to(logits.dtype), reduction="none")
    pos, neg = (mask & target).to(bce.dtype), (mask & ~target).to(bce.dtype)
    return (bce * pos).sum(1) / pos.sum(1).clamp(min=1) + (bce * neg).sum(1) / neg.sum(1).clamp(min=1)
