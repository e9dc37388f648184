"""Metrics, declared once: what each frame's record stores and what a leaderboard row aggregates from the records.

The results store (`runs.frames`), the leaderboard (`leaderboard.build`, so `run` and `evaluate`), training
validation and `compare --tolerance NAME=...` all read the `Metric`s here, with the plugins' ones
(`scoring.installed`); none spells a metric out itself.

To add a metric, declare it and register it from a plugin (or append it to BUILTIN for a core one):

    @hookimpl
    def register_metrics(register):
        register(Metric(
            "inlier_share",  # a record column (its per-frame value) and its name in validation and --tolerance
            column="inlier share (%) ↑",  # the leaderboard column of its aggregate
            higher_is_better=True,
            frame=lambda scored: scored.outcome.n_inliers / max(scored.outcome.n_matches, 1),
            aggregate="mean", scale=100.0, label="inlier share",
        ))

`frame` computes the per-frame value from a `Scored` frame when the frame runs (stored under `name`); `values`
instead derives a row's per-frame values from its records at aggregation time (Acc. does, because evaluate may move
the thresholds). `aggregate` is "proportion" (values 0/1; a percentage with a Wilson interval), "mean" (with a
bootstrap interval), "median" or "count"; NaN values are frames the aggregate leaves out.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from ..errors import PluginError
from .pose import PoseErrors, kept, success
from .protocol import Protocol

if TYPE_CHECKING:
    from ..stages.trace import FrameOutcome
    from ..types import Frame

ACC, RTE, RRE = "Acc. (%) ↑", "RTE (m) ↓", "RRE (°) ↓"
RTE_MEAN, RRE_MEAN = "rte_mean", "rre_mean"
GEODESIC_MEDIAN = "geodesic median (°) ↓"
INLIER_RATIO, TRUE_MATCHES = "inlier ratio (%) ↑", "true matches median ↑"
CHANCE, ACC_SKILL = "chance successes", "Acc. with true matches (%) ↑"
MIN_TRUE_MATCHES = 4  # fewer true matches than a PnP needs: a success on such a frame is luck, not registration
AGGREGATES = ("proportion", "mean", "median", "count")


@dataclass(frozen=True)
class Scored:
    """What a per-frame metric reads: the frame as the stages saw it (None when it failed to load), the pipeline's
    outcome (None when `evaluate` re-scores stored poses) and the pose errors."""

    frame: Frame | None
    outcome: FrameOutcome | None
    errors: PoseErrors


Values = Callable[[pd.DataFrame, Protocol], "np.ndarray | None"]  # a row's records -> [F] values, None: not recorded


@dataclass(frozen=True)
class Metric:
    """One metric: its per-frame value, its aggregate over a row's frames, which way is better and how it prints."""

    name: str  # record column of the per-frame value; key in training validation and compare's --tolerance
    column: str | None = None  # leaderboard column of the aggregate; None: stored per frame, not aggregated
    higher_is_better: bool | None = None
    frame: Callable[[Scored], float] | None = None  # per-frame value when the frame runs, stored as `name`
    values: Values | None = None  # per-frame values from a row's records (default: the records' `name` column)
    aggregate: str = "mean"  # one of AGGREGATES
    scale: float = 1.0  # the aggregate times this (100: a percentage)
    decimals: int | None = None  # the aggregate rounded to this many decimals
    fmt: str = ".2f"  # how the Markdown board prints the aggregate
    label: str = ""  # a short name for its interval columns ("Acc." -> "Acc. 95% low"); default: `name`
    from_poses: bool = False  # `frame` reads only the pose errors, so `evaluate` recomputes it from stored poses
    summary: str | None = None  # a "mean ± std" text column beside the mean (RTE, RRE)
    std: str | None = None  # the std (ddof 0, as the peers' scripts) column beside the mean

    def per_frame(self, records: pd.DataFrame, protocol: Protocol) -> np.ndarray | None:
        """[F] the values this metric aggregates over a row's records; None when the records predate it."""
        if self.values is not None:
            return self.values(records, protocol)
        if self.name not in records:
            return None
        return pd.to_numeric(records[self.name], errors="coerce").to_numpy(dtype=float)

    def reduce(self, values: np.ndarray | None) -> float:
        """The aggregate of per-frame values (NaN ones left out), scaled and rounded as the board shows it."""
        if values is None:
            return np.nan
        counted = pd.Series(values, dtype=float).dropna()
        if self.aggregate == "count":
            return int(counted.sum())
        if not len(counted):
            return np.nan
        value = self.scale * float(counted.median() if self.aggregate == "median" else counted.mean())
        return round(value, self.decimals) if self.decimals is not None else value

    @property
    def short(self) -> str:
        return self.label or self.name


def _success(records: pd.DataFrame, protocol: Protocol) -> np.ndarray:
    return success(records["rte_m"], records["rre_deg"], protocol).to_numpy()


def _kept_errors(column: str) -> Values:
    """A pose error on the frames inside the protocol's filter (NaN elsewhere): what RTE and RRE average."""

    def values(records: pd.DataFrame, protocol: Protocol) -> np.ndarray:
        inside = kept(records["rte_m"], records["rre_deg"], protocol).to_numpy()
        return np.where(inside, records[column].to_numpy(dtype=float), np.nan)

    return values


def _true_matches(records: pd.DataFrame) -> np.ndarray | None:
    return records["n_true_matches"].to_numpy(dtype=float) if "n_true_matches" in records else None


def _lucky(records: pd.DataFrame, protocol: Protocol) -> np.ndarray | None:
    """1 on successes with fewer than MIN_TRUE_MATCHES true matches (NaN: the matcher never ran, no true match)."""
    true = _true_matches(records)
    return None if true is None else (_success(records, protocol) & ~(true >= MIN_TRUE_MATCHES)).astype(float)


def _skill(records: pd.DataFrame, protocol: Protocol) -> np.ndarray | None:
    true = _true_matches(records)
    return None if true is None else (_success(records, protocol) & (true >= MIN_TRUE_MATCHES)).astype(float)


def _inlier_ratio(records: pd.DataFrame, protocol: Protocol) -> np.ndarray | None:
    """A frame's share of true matches, over frames whose matcher ran and returned matches."""
    true = _true_matches(records)
    if true is None or "n_matches" not in records:
        return None
    matches = records["n_matches"].to_numpy(dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(~np.isnan(true) & (matches > 0), true / matches, np.nan)


def _geodesic(records: pd.DataFrame, protocol: Protocol) -> np.ndarray | None:
    if "geodesic_deg" not in records:
        return None
    return records["geodesic_deg"].replace(np.inf, np.nan).to_numpy(dtype=float)


def true_matches(frame: Frame | None, outcome: FrameOutcome) -> float:
    """How many of the matcher's pairs are true under T_gt (within eps_c, or the matcher's own `Matches.radius_px`);
    NaN when the matcher did not run."""
    from ..geometry.correspondence import true_match_mask  # scipy: only when a frame is scored

    if frame is None or frame.T_gt is None or outcome.matched_uv is None or outcome.matched_xyz is None:
        return float("nan")
    radius = outcome.matches.radius_px if outcome.matches is not None else None
    return float(true_match_mask(frame, outcome.matched_uv, outcome.matched_xyz, radius).sum())


def _true_matches_recorded(scored: Scored) -> float:
    return true_matches(scored.frame, scored.outcome) if scored.outcome is not None else np.nan


def _count(attribute: str) -> Metric:
    return Metric(attribute, frame=lambda scored: getattr(scored.outcome, attribute))


BUILTIN: tuple[Metric, ...] = (
    Metric("rte_m", frame=lambda s: s.errors.rte_m, from_poses=True),
    Metric("rre_deg", frame=lambda s: s.errors.rre_deg, from_poses=True),
    Metric("geodesic_deg", frame=lambda s: s.errors.geodesic_deg, from_poses=True),
    _count("n_kp2d"),
    _count("n_kp3d"),
    _count("n_matches"),
    _count("n_inliers"),
    Metric("n_true_matches", frame=_true_matches_recorded),
    Metric("acc_pct", ACC, True, values=lambda r, p: _success(r, p).astype(float), aggregate="proportion",
           scale=100.0, decimals=2, label="Acc."),
    Metric("rte_mean", RTE_MEAN, False, values=_kept_errors("rte_m"), summary=RTE, std="rte_std", label="RTE"),
    Metric("rre_mean", RRE_MEAN, False, values=_kept_errors("rre_deg"), summary=RRE, std="rre_std", label="RRE"),
    Metric("geodesic_median", GEODESIC_MEDIAN, False, values=_geodesic, aggregate="median"),
    Metric("inlier_ratio", INLIER_RATIO, True, values=_inlier_ratio, scale=100.0, decimals=2, label="inlier ratio"),
    Metric("true_matches_median", TRUE_MATCHES, True, values=lambda r, p: _true_matches(r), aggregate="median",
           fmt=".2f"),
    Metric("chance", CHANCE, False, values=_lucky, aggregate="count", fmt="d"),
    Metric("skill_acc_pct", ACC_SKILL, True, values=_skill, aggregate="proportion", scale=100.0, decimals=2,
           label="Acc. with true matches"),
)  # fmt: skip


def check(metric: Any, plugin: str) -> Metric:
    """A plugin's registration, refused (naming the plugin) unless it is a usable Metric."""
    if not isinstance(metric, Metric):
        raise PluginError(f"plugin {plugin!r} registered {metric!r} as a metric, but it is no i2pbench.api.Metric")
    if not metric.name or metric.aggregate not in AGGREGATES:
        raise PluginError(f"plugin {plugin!r}: metric {metric.name!r} needs a name and an aggregate in {AGGREGATES}")
    if metric.column and metric.higher_is_better is None:
        raise PluginError(f"plugin {plugin!r}: metric {metric.name!r} has a column but no higher_is_better")
    if metric.frame is None and metric.values is None:
        raise PluginError(f"plugin {plugin!r}: metric {metric.name!r} needs `frame` (per frame) or `values`")
    return metric
