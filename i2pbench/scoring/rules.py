"""Scoring rules: how one paper's evaluation code turns per-frame poses into Acc., mean and std.

The peers' scripts differ in four places (docs/protocol.md, "Protocol cards"): the rotation error (sum of absolute
'xzy' Euler angles, the geodesic angle, or ICL's yaw-only angle), what a failed PnP becomes (an infinite error, a
frame left out, or the identity pose), which frames enter mean and std (a threshold filter, or all), and the std's
ddof. `frame_errors` applies a card's rules to per-frame records (T_pred and T_gt as the store keeps them); `summarize`
aggregates them. Both read only the records, so any finished run can be re-scored without running a network.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..geometry import invert
from ..metrics import xzy_euler_deg

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


def frame_errors(records: pd.DataFrame, rules: ScoringRules) -> pd.DataFrame:
    """Per record: `rte`, `rre` under the rules, `failed` (no usable pose) and `scored` (enters Acc.; False for a
    frame the rules leave out). A frame with no ground truth (its data failed to load) is infinite, or skipped."""
    rows = [
        _frame(pred, gt, inliers, matches, rules)
        for pred, gt, inliers, matches in zip(
            records["T_pred"], records["T_gt"], _column(records, "n_inliers"), _column(records, "n_matches"),
            strict=True,
        )
    ]  # fmt: skip
    return pd.DataFrame(rows, columns=["rte", "rre", "failed", "scored"], index=records.index)


def summarize(errors: pd.DataFrame, rules: ScoringRules) -> dict[str, float]:
    """Acc. (%) over the scored frames; mean and std (ddof of the rules) over the scored frames the filter keeps."""
    scored = errors[errors["scored"]]
    rte, rre = scored["rte"].to_numpy(float), scored["rre"].to_numpy(float)
    kept = _below(rte, rules.filter_rte_m) & _below(rre, rules.filter_rre_deg)
    nan = float("nan")
    enough = int(kept.sum()) > rules.ddof
    return {
        "acc_pct": 100.0 * float(((rre < rules.acc_rre_deg) & (rte < rules.acc_rte_m)).mean()) if len(rte) else nan,
        "rte_mean": float(np.mean(rte[kept])) if kept.any() else nan,
        "rte_std": float(np.std(rte[kept], ddof=rules.ddof)) if enough else nan,
        "rre_mean": float(np.mean(rre[kept])) if kept.any() else nan,
        "rre_std": float(np.std(rre[kept], ddof=rules.ddof)) if enough else nan,
        "kept": int(kept.sum()),
        "scored": len(rte),
    }


def score(records: pd.DataFrame, rules: ScoringRules) -> dict[str, float]:
    """`summarize` of `frame_errors`: one row's numbers under the rules."""
    with np.errstate(invalid="ignore", over="ignore"):  # an inf among kept frames gives an inf mean, a nan std
        return summarize(frame_errors(records, rules), rules)


def _below(values: np.ndarray, threshold: float) -> np.ndarray:
    """values < threshold; an infinite threshold is no filter at all, so an infinite error passes it too."""
    return np.ones(len(values), bool) if math.isinf(threshold) else values < threshold


def _column(records: pd.DataFrame, name: str) -> pd.Series:
    return records[name] if name in records else pd.Series(np.nan, index=records.index)


def _matrix(values) -> np.ndarray | None:
    if values is None or (np.ndim(values) == 0 and pd.isna(values)):
        return None
    return np.asarray(values, np.float64).reshape(4, 4)


def _frame(pred, gt, inliers, matches, rules: ScoringRules) -> tuple[float, float, bool, bool]:
    T_gt, T_pred = _matrix(gt), _matrix(pred)
    failed = T_pred is None or not np.isfinite(T_pred).all()
    failed = failed or bool(np.linalg.norm(T_pred[:3, 3]) >= rules.max_translation_m)
    if T_gt is None or (failed and rules.failure != "identity"):
        return math.inf, math.inf, True, rules.failure != "skip"
    if failed:
        T_pred = np.eye(4)
    elif rules.drop_all_inliers and _all_inliers(inliers, matches):
        return *_errors(T_pred, T_gt, rules), False, False
    return *_errors(T_pred, T_gt, rules), failed, True


def _all_inliers(inliers, matches) -> bool:
    """DeepI2P's cost is the PnP outlier ratio 1 - inliers / matches; its analysis drops cost <= 1e-6, i.e. 0."""
    return bool(pd.notna(inliers) and pd.notna(matches) and matches > 0 and inliers >= matches)


def _errors(T_pred: np.ndarray, T_gt: np.ndarray, rules: ScoringRules) -> tuple[float, float]:
    P_diff = invert(T_pred) @ T_gt
    rte = np.linalg.norm(P_diff[:3, 3]) if rules.rte == "p-diff" else np.linalg.norm(T_gt[:3, 3] - T_pred[:3, 3])
    return float(rte), rre_deg(T_pred, T_gt, P_diff[:3, :3], rules.rre)


def rre_deg(T_pred: np.ndarray, T_gt: np.ndarray, R_diff: np.ndarray, kind: str) -> float:
    """The rotation error of one frame under `kind`: the Euler sum and the geodesic angle of R_diff, or ICL's angle
    between the 2-vectors (R[2,0], R[0,0]) of ground truth and estimate, not normalised, the cosine clipped."""
    if kind == "xzy-sum":
        return float(np.abs(xzy_euler_deg(R_diff)).sum())
    if kind == "geodesic":
        return float(np.degrees(np.arccos(np.clip((np.trace(R_diff) - 1.0) / 2.0, -1.0, 1.0))))
    cos = np.dot(T_gt[[2, 0], 0], T_pred[[2, 0], 0])
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
