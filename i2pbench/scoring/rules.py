"""Scoring rules: how one paper's evaluation code turns per-frame poses into Acc., mean and std.

The peers' scripts differ in four places (docs/protocol.md, "Protocol cards"): the rotation error (sum of absolute
'xzy' Euler angles, the geodesic angle, or ICL's yaw-only angle), what a failed PnP becomes (an infinite error, a
frame left out, or the identity pose), which frames enter mean and std (a threshold filter, or all), and the std's
ddof. `ScoringRules` declares them (and imports nothing heavy, so registering cards costs `i2pbench plugins`
nothing); `scoring.score` applies them to stored records.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

RRE_KINDS = ("xzy-sum", "geodesic", "yaw-2d")
RTE_KINDS = ("p-diff", "t-diff")
FAILURE_KINDS = ("inf", "skip", "identity")


@dataclass(frozen=True)
class ScoringRules:
    """One evaluation script's rules; thresholds in degrees and metres, math.inf for 'no filter'."""

    rre: str = "xzy-sum"  # xzy-sum: sum |extrinsic 'xzy' Euler| of P_diff; geodesic; yaw-2d: ICL's (R[2,0], R[0,0])
    rte: str = "p-diff"  # p-diff: ||(inv(T_pred) @ T_gt)[:3, 3]||; t-diff: ||t_gt - t_pred|| (ICL)
    failure: str = "inf"  # a frame without a pose: inf (a miss, kept), skip (left out of everything), identity
    max_translation_m: float = math.inf  # an estimate with ||t_pred|| >= this is a failure (DeepI2P's 14.14 m)
    drop_all_inliers: bool = False  # leave out a solved frame whose every match is a RANSAC inlier (DeepI2P cost 0)
    acc_rre_deg: float = 5.0  # success: RRE < this and RTE < acc_rte_m, over the frames scored
    acc_rte_m: float = 2.0
    filter_rre_deg: float = 10.0  # mean and std over scored frames with RRE < this and RTE < filter_rte_m
    filter_rte_m: float = 5.0
    ddof: int = 0  # of the std (numpy's default 0 in every peer's script)

    def __post_init__(self) -> None:
        for field, value, kinds in (
            ("rre", self.rre, RRE_KINDS),
            ("rte", self.rte, RTE_KINDS),
            ("failure", self.failure, FAILURE_KINDS),
        ):
            if value not in kinds:
                raise ValueError(f"scoring rule {field}={value!r}; known: {', '.join(kinds)}")
