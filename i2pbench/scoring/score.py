"""Scores under a card's rules (`rules.ScoringRules`), from per-frame records as the store keeps them.

`frame_errors` applies the rules to each record's T_pred and T_gt; `summarize` aggregates them. Both read only the
records, so any finished run can be re-scored without running a network.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from ..geometry.transforms import invert
from .pose import xzy_euler_deg
from .rules import ScoringRules


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
