"""Overlay figures: the LiDAR cloud projected under the initial, ground-truth and predicted poses (EdgeRegNet Fig. 7).

Under the ground truth the points must sit on the objects they hit (car outlines, poles); under the initial pose
they land wherever the protocol's random transform throws them; the predicted panel shows how close a method got.
Optional panels show the edge points both extractors kept and the matches, each drawn against the ground truth.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..errors import I2PBenchError
from ..geometry.transforms import project
from ..scoring.pose import pose_errors
from ..types import Frame, Keypoints2D, Keypoints3D, Matches
from . import draw

INLIER, OUTLIER = (40, 230, 40), (240, 40, 40)
EDGE2D, EDGE3D = (0, 230, 255), (255, 0, 220)


def points_panel(frame: Frame, T: np.ndarray | None, radius: int = 1) -> np.ndarray:
    """The grey image with every LiDAR point that lands in it under T, coloured by distance (the image alone if T
    is None, e.g. a failed solve)."""
    canvas = draw.background(frame.image)
    if T is None:
        return canvas
    uv, distance, _ = draw.project_points(frame.K, T, frame.points[:, :3], frame.image_size)
    return draw.draw_points(canvas, uv, draw.distance_colours(distance), distance, radius)


RRE_NOTE = (
    "RRE is the peers' sum of the three absolute 'xzy' Euler angles, so one frame's RRE runs up to 450° "
    "(180 + 90 + 180), past 360°; the geodesic angle, at most 180°, is the rotation error itself"
)


def rre_text(rre_deg: float, geodesic_deg: float, unit: str = " deg") -> str:
    """One frame's RRE; past 180°, which no rotation angle exceeds, it says it is an Euler sum and adds the geodesic."""
    if rre_deg > 180:
        return f"RRE {rre_deg:.2f}{unit} (sum of 3 Euler angles; geodesic {geodesic_deg:.2f}{unit})"
    return f"RRE {rre_deg:.2f}{unit}"


def errors_text(T: np.ndarray | None, T_gt: np.ndarray | None) -> str:
    """ "RTE 0.12 m, RRE 1.30 deg" of T against the ground truth ("" when either is missing)."""
    if T is None or T_gt is None:
        return ""
    errors = pose_errors(T, T_gt)
    return f"RTE {errors.rte_m:.2f} m, {rre_text(errors.rre_deg, errors.geodesic_deg)}"


def pose_panels(frame: Frame, T_pred: np.ndarray | None, title: str = "", failure: str = "", radius: int = 1):
    """[(caption lines, panel)] for the initial, ground-truth and predicted poses, errors measured against T_gt."""
    predicted = errors_text(T_pred, frame.T_gt) if T_pred is not None else f"failed: {failure or 'no pose'}"
    captions = {
        "initial pose (T_init)": (frame.T_init, errors_text(frame.T_init, frame.T_gt)),
        "ground truth (T_gt)": (frame.T_gt, ""),
        "predicted": (T_pred, predicted),
    }
    return [
        ([f"{title}{name}: {text}".rstrip(": ")], points_panel(frame, T, radius))
        for name, (T, text) in captions.items()
    ]


def edges_panel(frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D) -> tuple[list[str], np.ndarray]:
    """2D edge pixels (cyan) and 3D edge points projected under the ground truth (magenta): where the two coincide,
    a matcher has something to find."""
    canvas = draw.background(frame.image, brightness=0.6)
    draw.draw_points(canvas, kp2d.uv, EDGE2D, radius=1)
    uv, distance, _ = draw.project_points(frame.K, frame.T_gt, kp3d.xyz, frame.image_size)
    draw.draw_points(canvas, uv, EDGE3D, distance, radius=2)
    return [f"edges: {len(kp2d)} 2D (cyan), {len(kp3d)} 3D under ground truth (magenta, {len(uv)} in view)"], canvas


def matches_panel(
    frame: Frame, kp2d: Keypoints2D, kp3d: Keypoints3D, matches: Matches, inliers: np.ndarray
) -> tuple[list[str], np.ndarray]:
    """Each match as a line from its 2D point to its 3D point projected under the ground truth, so a correct match
    is a dot and a wrong one a long line; solver inliers green, outliers red (outliers drawn first)."""
    canvas = draw.background(frame.image, brightness=0.6)
    is_inlier = np.zeros(len(matches), bool)
    is_inlier[np.asarray(inliers, dtype=np.int64)] = True
    uv3, front = _project_all(frame, kp3d.xyz[matches.index3d])
    for keep, colour in ((~is_inlier, OUTLIER), (is_inlier, INLIER)):
        for a, b in zip(kp2d.uv[matches.index2d][keep & front], uv3[keep & front], strict=True):
            cv2.line(canvas, _cv_point(a), _cv_point(b), colour, 1, cv2.LINE_AA)
            cv2.circle(canvas, _cv_point(a), 2, colour, -1, cv2.LINE_AA)
    n_in = int(is_inlier.sum())
    return [
        f"matches: {len(matches)}, {n_in} inliers (green), {len(matches) - n_in} outliers (red); "
        "line = 2D point to its 3D point under ground truth"
    ], canvas


def _project_all(frame: Frame, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of every point (in front or not) under the ground truth, clipped to a frame around the image."""
    uv, front = project(frame.K, frame.T_gt, np.asarray(xyz, dtype=np.float64))
    w, h = frame.image_size
    return np.clip(uv, [-w, -h], [2 * w, 2 * h]), front


def _cv_point(uv: np.ndarray) -> tuple[int, int]:
    return int(round(float(uv[0]))), int(round(float(uv[1])))


def compose(panels: list[tuple[list[str], np.ndarray]], with_legend: bool = True) -> np.ndarray:
    """Captioned panels stacked top to bottom, the distance legend last: one RGB image [H x W x 3]."""
    width = panels[0][1].shape[1]
    parts = [part for lines, panel in panels for part in (draw.caption(lines, width), panel)]
    return draw.stack(parts + ([draw.legend(width)] if with_legend else []))


def figure_size(frame: Frame, n_panels: int, with_legend: bool = True) -> tuple[int, int]:
    """(width, height) of `compose`'s output for one-line captions: callers and tests know the size up front."""
    w, h = frame.image_size
    return w, n_panels * (h + draw.CAPTION_PX) + (draw.CAPTION_PX if with_legend else 0)


def write_png(path: str | Path, image: np.ndarray) -> None:
    """Write an RGB array as PNG (OpenCV wants BGR), creating the parent directory."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), np.ascontiguousarray(image[:, :, ::-1])):
        raise I2PBenchError(f"could not write {path}")
