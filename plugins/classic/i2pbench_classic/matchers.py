"""Matchers without learned parameters: mutual nearest neighbours on cosine similarity (with a training loss for the
encoders in front of it) and the ground-truth oracle that bounds what any matcher can do with given keypoints.

torch is imported where descriptors are compared, so that the oracle (numpy only) runs without it."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from i2pbench.api import (
    GROUND_TRUTH,
    KEYPOINTS2D,
    KEYPOINTS3D,
    MATCHES,
    Features,
    Frame,
    Keypoints2D,
    Keypoints3D,
    Matcher,
    Matches,
    StageError,
    ground_truth_matches,
)

if TYPE_CHECKING:
    import torch


def cosine_similarity(desc2d: torch.Tensor, desc3d: torch.Tensor) -> torch.Tensor:
    """[M2 x M3] cosine similarities of [M2 x D] and [M3 x D] descriptors."""
    import torch.nn.functional as F

    return F.normalize(desc2d.float(), dim=-1) @ F.normalize(desc3d.float(), dim=-1).T


def mutual_nearest(sim: torch.Tensor, min_similarity: float) -> Matches:
    """Pairs (i, j) where j is i's best column, i is j's best row, and sim[i, j] >= min_similarity."""
    import torch

    if sim.numel() == 0:
        return Matches.empty()
    best3d = sim.argmax(dim=1)
    best2d = sim.argmax(dim=0)
    rows = torch.arange(sim.shape[0])
    keep = (best2d[best3d] == rows) & (sim[rows, best3d] >= min_similarity)
    i2, i3 = rows[keep], best3d[keep]
    return Matches(i2.numpy().astype(np.int64), i3.numpy().astype(np.int64), sim[i2, i3].numpy().astype(np.float32))


def dual_softmax_nll(
    sim: torch.Tensor, index2d: torch.Tensor, index3d: torch.Tensor, temperature: float
) -> torch.Tensor:
    """Mean -log P[i, j] over ground-truth pairs, P = softmax over rows * softmax over columns of sim / temperature."""
    logits = sim / temperature
    log_p = logits.log_softmax(dim=0) + logits.log_softmax(dim=1)
    return -log_p[index2d, index3d].mean()


class CosineMatcher(Matcher):
    """Mutual nearest neighbours on cosine similarity; `loss` trains the encoders in front of it (TrainableMatcher)."""

    name = "cosine"
    default_conf: ClassVar[dict[str, Any]] = {
        "min_similarity": 0.0,  # drop mutual pairs whose cosine similarity is below this
        "temperature": 0.1,  # of the dual softmax in `loss`
        "radius_px": None,  # eps_c of the training pairs; None uses frame.match_radius_px
    }

    def similarity(self, features: Features) -> torch.Tensor:
        if features.desc2d is None or features.desc3d is None:
            raise StageError(self.label, "needs descriptors on both sides; put encoders in front of it")
        return cosine_similarity(features.desc2d, features.desc3d)

    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Matches:
        import torch

        with torch.no_grad():
            return mutual_nearest(self.similarity(features), float(self.conf["min_similarity"]))

    def loss(
        self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """Dual-softmax negative log-likelihood of the ground-truth pairs (ground_truth_matches with eps_c)."""
        import torch

        sim = self.similarity(features)
        gt = ground_truth_matches(frame, kp2d, kp3d, self.conf["radius_px"])
        if len(gt) == 0:  # nothing to supervise; a zero that keeps the graph so a training step still runs
            return sim.sum() * 0.0, {"nll": 0.0, "gt_pairs": 0.0}
        loss = dual_softmax_nll(
            sim, torch.from_numpy(gt.index2d), torch.from_numpy(gt.index3d), float(self.conf["temperature"])
        )
        return loss, {"nll": float(loss.detach()), "gt_pairs": float(len(gt))}


class OracleMatcher(Matcher):
    """Each 3D keypoint paired with its nearest 2D keypoint under the ground-truth pose, when within eps_c.

    The upper bound of matching for a pair of extractors: it isolates extractor and solver quality from features.
    Score = -reprojection distance in pixels, so closer pairs rank higher.
    """

    name = "oracle"
    consumes = frozenset({KEYPOINTS2D, KEYPOINTS3D, GROUND_TRUTH})
    provides = frozenset({MATCHES})
    default_conf: ClassVar[dict[str, Any]] = {
        "radius_px": None,  # eps_c; None uses frame.match_radius_px (3 px by default)
    }

    def __call__(self, frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, features: Features) -> Matches:
        if frame.T_gt is None:
            raise StageError(self.label, "needs the ground-truth pose (frame.T_gt); it was hidden from this stage")
        gt = ground_truth_matches(frame, kp2d, kp3d, self.conf["radius_px"])
        return Matches(gt.index2d, gt.index3d, (-gt.distance_px).astype(np.float32))
