"""Edge-quality diagnostics: how many 3D edge points land within eps_c of a 2D edge pixel under the true pose.

That share is what a matcher can at best recover and what a training loss gets as positives (the paper wants more
than 10%). It is reported among the 3D points that project into the image and over all of them, next to the chance
level (`coverage2d`: the share of image pixels within eps_c of some 2D keypoint, i.e. the ratio 3D points scattered
at random over the image would get), so an extractor pair is judged by its `lift` over chance, not only its ratio.
A LiDAR sees only part of the image (not the sky), so even random 3D points show a lift above 1: the pair with the
"random" 3D extractor is the empirical chance level for a 2D extractor.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from typing import Any

import cv2
import numpy as np
import pandas as pd

from ..geometry.correspondence import ground_truth_matches
from ..stages.components import Extractor2D, Extractor3D
from ..types import Frame, Keypoints2D, Keypoints3D

PAPER_TARGET_RATIO = 0.10  # "the ratio of actual matching points to the total can exceed 10%"


def image_coverage(kp2d: Keypoints2D, size: tuple[int, int], radius_px: float) -> float:
    """Share of the image's pixel centres closer than radius_px to a 2D keypoint (keypoints rounded to pixels)."""
    width, height = size
    if len(kp2d) == 0:
        return 0.0
    seeds = np.full((height, width), 255, np.uint8)
    uv = np.rint(kp2d.uv).astype(np.int64)
    uv = uv[(uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)]
    seeds[uv[:, 1], uv[:, 0]] = 0
    distance = cv2.distanceTransform(seeds, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return float((distance < radius_px).mean())


def timed(extractor: Extractor2D | Extractor3D, frame: Frame) -> tuple[Any, float]:
    """(keypoints, milliseconds); the extractor sees the frame without its ground truth, as in a pipeline."""
    start = time.perf_counter()
    keypoints = extractor(frame.without_ground_truth())
    return keypoints, 1e3 * (time.perf_counter() - start)


def pair_row(frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, radius_px: float | None) -> dict[str, Any]:
    """Counts and ratios of one extractor pair on one frame."""
    radius = frame.match_radius_px if radius_px is None else radius_px
    gt = ground_truth_matches(frame, kp2d, kp3d, radius)
    n_fov, n_matched = int(gt.in_fov3d.sum()), int(gt.matchable3d.sum())
    coverage = image_coverage(kp2d, frame.image_size, radius)
    ratio_fov = n_matched / n_fov if n_fov else float("nan")
    return {
        "n2d": len(kp2d),
        "n3d": len(kp3d),
        "n3d_in_fov": n_fov,
        "n3d_matched": n_matched,
        "ratio_in_fov": ratio_fov,
        "ratio_all": n_matched / len(kp3d) if len(kp3d) else float("nan"),
        "ratio2d": float(gt.matchable2d.mean()) if len(kp2d) else float("nan"),
        "coverage2d": coverage,
        "lift": ratio_fov / coverage if coverage > 0 else float("nan"),
        "radius_px": float(radius),
    }


def edge_diagnostics_grid(
    frames: Iterable[Frame],
    extractors2d: Sequence[Extractor2D],
    extractors3d: Sequence[Extractor3D],
    radius_px: float | None = None,
) -> pd.DataFrame:
    """One row per (frame, 2D extractor, 3D extractor); each extractor runs once per frame and is timed."""
    rows = []
    for frame in frames:
        if frame.T_gt is None:
            raise ValueError(f"edge diagnostics need ground truth; frame {frame.frame_id!r} has no T_gt")
        out2d = [timed(e, frame) for e in extractors2d]
        out3d = [timed(e, frame) for e in extractors3d]
        for e2, (kp2d, ms2d) in zip(extractors2d, out2d, strict=True):
            for e3, (kp3d, ms3d) in zip(extractors3d, out3d, strict=True):
                head = {
                    "dataset": frame.dataset,
                    "frame_id": frame.frame_id,
                    "extractor2d": e2.name,
                    "extractor3d": e3.name,
                }
                rows.append({**head, **pair_row(frame, kp2d, kp3d, radius_px), "time2d_ms": ms2d, "time3d_ms": ms3d})
    return pd.DataFrame(rows)


def edge_diagnostics(
    frames: Iterable[Frame], extractor2d: Extractor2D, extractor3d: Extractor3D, radius_px: float | None = None
) -> pd.DataFrame:
    """One row per frame for one extractor pair (columns as `edge_diagnostics_grid`)."""
    return edge_diagnostics_grid(frames, [extractor2d], [extractor3d], radius_px)


def summarize_edge_diagnostics(rows: pd.DataFrame) -> pd.DataFrame:
    """One row per extractor pair: mean counts and ratios, the pooled in-FOV ratio (all matched / all in FOV), the
    share of frames reaching the paper's 10%, and the median extraction times."""
    grouped = rows.groupby(["extractor2d", "extractor3d"], sort=False)
    summary = grouped.agg(
        frames=("frame_id", "size"),
        n2d=("n2d", "mean"),
        n3d=("n3d", "mean"),
        n3d_in_fov=("n3d_in_fov", "mean"),
        ratio_in_fov=("ratio_in_fov", "mean"),
        ratio_all=("ratio_all", "mean"),
        coverage2d=("coverage2d", "mean"),
        lift=("lift", "mean"),
        time2d_ms=("time2d_ms", "median"),
        time3d_ms=("time3d_ms", "median"),
    )
    pooled = grouped["n3d_matched"].sum() / grouped["n3d_in_fov"].sum().replace(0, np.nan)
    summary.insert(5, "ratio_in_fov_pooled", pooled)
    summary["frames_over_target"] = grouped["ratio_in_fov"].apply(lambda r: float((r > PAPER_TARGET_RATIO).mean()))
    return summary.reset_index()
