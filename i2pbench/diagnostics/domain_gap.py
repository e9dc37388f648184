"""Domain-gap statistics: how far one dataset's frames are from another's (e.g. the synthetic set from real KITTI).

A method trained on synthetic frames meets real ones at test time; where their edge counts, LiDAR range and
reflectance histograms or image gradients differ, the learned stages see inputs they never trained on. Each frame
gives a flat dict of statistics (`frame_statistics`), a dataset is summarised by their mean and spread over frames
(`summarize`), and two summaries are set side by side with their ratio and difference (`side_by_side`), so the gap
is a table to read and to track while the synthetic set is brought closer to the real data.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import pandas as pd

from ..boards import leaderboard
from ..geometry.transforms import in_image, project
from ..registry.catalog import Registry
from ..stages.components import Extractor2D, Extractor3D
from ..types import Frame
from .edges import pair_row

EDGE_EXTRACTORS = {  # counted uncapped: the cap (3000 by default) would flatten every gap in counts
    "lsd": "extractor2d",
    "canny": "extractor2d",
    "depth": "extractor3d",
    "reflectance": "extractor3d",
    "depth+reflectance": "extractor3d",
}
PAIR = ("lsd", "depth+reflectance")  # the paper's pair, run with diagnose's defaults so the lift matches diagnose
GRADIENT_THRESHOLD = 150.0  # the sobel extractor's threshold: strong_gradient is the share of pixels sobel marks
FAR_M = 40.0  # range_over_40m's limit


@dataclass(frozen=True)
class GapExtractors:
    """The registered extractors the statistics run: uncapped ones for the counts, the default pair for the lift."""

    edges: Mapping[str, Extractor2D | Extractor3D]  # EDGE_EXTRACTORS name -> extractor with max_keypoints None
    pair2d: Extractor2D
    pair3d: Extractor3D


def gap_extractors(registry: Registry) -> GapExtractors:
    """Build the extractors by name, so the core never imports the plugins that register them."""
    edges = {}
    for name, kind in EDGE_EXTRACTORS.items():
        cls = registry.component(kind, name)
        edges[name] = cls({"max_keypoints": None} if "max_keypoints" in cls.default_conf else {})
    pair2d, pair3d = registry.component("extractor2d", PAIR[0])(), registry.component("extractor3d", PAIR[1])()
    return GapExtractors(edges, pair2d, pair3d)


def edge_counts(frame: Frame, extractors: Mapping[str, Extractor2D | Extractor3D]) -> dict[str, float]:
    """Keypoints each extractor finds; the extractors see the frame without ground truth, as in a pipeline."""
    blind = frame.without_ground_truth()
    unit = {"extractor2d": "pixels", "extractor3d": "points"}
    return {f"{name}_{unit[e.kind]}": float(len(e(blind))) for name, e in extractors.items()}


def pair_statistics(frame: Frame, extractor2d: Extractor2D, extractor3d: Extractor3D) -> dict[str, float]:
    """diagnose's ratio, chance level and lift for one pair on one frame (diagnostics.pair_row, not a rewrite)."""
    blind = frame.without_ground_truth()
    row = pair_row(frame, extractor2d(blind), extractor3d(blind), None)
    return {key: float(row[key]) for key in ("ratio_in_fov", "coverage2d", "lift")}


def deciles(prefix: str, values: np.ndarray) -> dict[str, float]:
    """The 10th, 50th and 90th percentiles (numpy's linear interpolation) as {prefix}_q10, _q50, _q90."""
    return {f"{prefix}_q{q}": float(np.quantile(values, q / 100)) for q in (10, 50, 90)}


def lidar_statistics(frame: Frame) -> dict[str, float]:
    """Scan size, field-of-view share, range and reflectance histograms, rings."""
    if frame.T_gt is None:
        raise ValueError(f"domain-gap statistics need ground truth; frame {frame.frame_id!r} has no T_gt")
    uv, front = project(frame.K, frame.T_gt, frame.points[:, :3].astype(np.float64))
    ranges, refl = frame.ranges.astype(np.float64), frame.points[:, 3].astype(np.float64)
    stats = {"points": float(len(ranges)), "in_fov": float(in_image(uv, front, frame.image_size).mean())}
    stats |= deciles("range", ranges) | {"range_over_40m": float((ranges > FAR_M).mean())}
    stats |= deciles("reflectance", refl)
    stats["reflectance_zero"] = float((refl == 0).mean())
    stats["rings"] = float(np.unique(frame.ring).size)
    return stats


def image_statistics(frame: Frame, gradient_threshold: float = GRADIENT_THRESHOLD) -> dict[str, float]:
    """Grey-level mean and spread, and the 3x3 Sobel magnitude as the 2D extractors see it (OpenCV's reflected
    border, so a pixel on the image edge has no gradient across it)."""
    grey = cv2.cvtColor(np.ascontiguousarray(frame.image), cv2.COLOR_RGB2GRAY)
    magnitude = cv2.magnitude(cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3))
    return {
        "grey_mean": float(grey.mean()),
        "grey_std": float(grey.std()),
        "gradient_mean": float(magnitude.mean()),
        "gradient_q90": float(np.quantile(magnitude, 0.9)),
        "strong_gradient": float((magnitude > gradient_threshold).mean()),
    }


def frame_statistics(
    frame: Frame, extractors: GapExtractors, gradient_threshold: float = GRADIENT_THRESHOLD
) -> dict[str, float]:
    """Every statistic of one frame with ground truth, in table order (`i2pbench domain-gap --help` lists them)."""
    return {
        **edge_counts(frame, extractors.edges),
        **pair_statistics(frame, extractors.pair2d, extractors.pair3d),
        **lidar_statistics(frame),
        **image_statistics(frame, gradient_threshold),
    }


def summarize(rows: pd.DataFrame) -> pd.DataFrame:
    """Mean and std (over the frames given: ddof 0) of each statistic, indexed by statistic; NaNs are skipped."""
    summary = pd.DataFrame({"mean": rows.mean(), "std": rows.std(ddof=0)})
    frames = pd.DataFrame({"mean": [float(len(rows))], "std": [np.nan]}, index=["frames"])
    return pd.concat([frames, summary])


def summarize_frames(
    frames: Iterable[Frame], extractors: GapExtractors, gradient_threshold: float = GRADIENT_THRESHOLD
) -> pd.DataFrame:
    """`summarize` of every frame's `frame_statistics`."""
    return summarize(pd.DataFrame([frame_statistics(f, extractors, gradient_threshold) for f in frames]))


def side_by_side(summary: pd.DataFrame, against: pd.DataFrame, labels: tuple[str, str]) -> pd.DataFrame:
    """One row per statistic: each dataset's mean and std, then ratio = mean / against mean (NaN where the against
    mean is 0) and difference = mean - against mean."""
    names = [name for name in summary.index if name in against.index]
    a, b = summary.loc[names], against.loc[names]
    table = pd.DataFrame({"statistic": names})
    for label, part in zip(labels, (a, b), strict=True):
        table[f"{label} mean"], table[f"{label} std"] = part["mean"].to_numpy(), part["std"].to_numpy()
    ratio = a["mean"] / b["mean"].where(b["mean"] != 0)
    table["ratio"], table["difference"] = ratio.to_numpy(), (a["mean"] - b["mean"]).to_numpy()
    return table


def format_number(value: Any) -> str:
    """Counts as integers, small values to 3 significant digits, NaN as '-' (as the leaderboards show it)."""
    if pd.isna(value):
        return "-"
    return f"{value:.0f}" if abs(value) >= 100 else f"{value:.3g}"


def to_markdown(table: pd.DataFrame) -> str:
    """The side-by-side table as Markdown, numbers formatted by `format_number` (the leaderboards' writer)."""
    shown = table.copy()
    for column in shown.columns[1:]:
        shown[column] = shown[column].map(format_number)
    return leaderboard.to_markdown(shown, list(shown.columns))
